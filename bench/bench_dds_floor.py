"""The floor under the live graph's cost: one tick's DDS messages alone, against direct mode's whole tick.

    .venv/bin/python bench/bench_dds_floor.py [--sim-s 800] [--ticks 4000]

First the alignment campaign runs in direct mode for --sim-s of sim time (nominal truth, seed 1, bag
recorded): its wall time per tick, start-up included, is the baseline, and its bag gives each topic's
messages per tick and a real payload (a sample topic travels as its per-tick block, topics.SAMPLE_BLOCKS).
Then the alignment graph's traffic is replayed in one process under one EventsExecutor, as
`sofia run` runs it: a node per graph node, each topic published by its node and taken raw by its
subscribers and the recorder, the handshake's done reports by the nodes that wait on them (the cores'
upstream lists, the recorder, the clock). The callbacks only count; the next tick is published from
the callback that takes the last message of the current one, so the loop is the graph's lock-step
with no work in it. Printed per tick: publishes, deliveries, wall time and its share of direct mode's
tick, for the data, for the handshake, and for both: the executor/direct ratio no tuning of the
nodes' Python can go below while every message travels over DDS.
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rclpy.task import Future
from std_msgs.msg import String

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.campaigns.alignment import graph_config, run_alignment
from sofia_ros.config import load_effect_config
from sofia_ros.nodes.domain import claimed_ros_domain
from sofia_ros.nodes.shell import message_class
from sofia_ros.nodes.sync import DATA_QOS, SYNC_QOS, done_topic
from sofia_ros.sim.graph import build_cores, graph_topics
from sofia_ros.topics import CLOCK, DEFAULT_TICK_NS, SAMPLE_BLOCKS

from results_file import Transcript, current_load, write_results

ROOT = Path(__file__).resolve().parents[1]
#: Every line printed, for bench/results/dds_floor.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say
#: A done report as the nodes send it (nodes.shell.LockstepNode.publish_done), for its size.
DONE_REPORT = '1234;0;;/tascu/attitude=1234,/tascu/command_status=61,/tascu/fd_command=1234,/tascu/motion_status=1234'


def direct_baseline(sim_s, folder):
    """Direct mode's wall time per tick, and per wire topic (messages per tick, one payload) from its bag."""
    truth = load_effect_config(ROOT / 'config/truth/nominal.yaml')
    started = time.perf_counter()
    run = run_alignment(truth, seed=1, bag_path=folder / 'direct', mode='direct', max_sim_s=sim_s)
    wall_s = time.perf_counter() - started
    ticks = round(run.summary['sim_seconds'] * m.NS_PER_S / DEFAULT_TICK_NS)
    traffic = {}
    with BagReader(folder / 'direct') as bag:
        counts = {topic.name: topic.count for topic in bag.topics if topic.count}
        firsts = bag.messages_by_topic(*counts, raw=tuple(counts))
    for topic, count in counts.items():
        if topic in SAMPLE_BLOCKS:
            # Every sample of a tick has the first sample's length: one block of them is one tick's message.
            first_sample = bytes(firsts[topic][1][0])
            traffic[SAMPLE_BLOCKS[topic].name] = (1.0, m.sample_block_cdr([first_sample] * (count // ticks)))
        else:
            traffic[topic] = (count / ticks, bytes(firsts[topic][1][0]))
    return wall_s / ticks, ticks, traffic


class TrafficGraph:
    """The graph's nodes with the publishers and raw subscriptions of the chosen traffic, under one executor."""

    def __init__(self, traffic, fan_out, msgtypes):
        self.executor = EventsExecutor()
        self.nodes = {}
        self.publishers = {}
        self.expected_per_topic = {topic: len(subscribers) for topic, (_, subscribers) in fan_out.items()}
        self.traffic = traffic
        self.taken = 0
        self.due = 0
        self.tick = 0
        self.last_tick = 0
        self.finished = Future()
        for topic, (publisher, subscribers) in fan_out.items():
            qos = SYNC_QOS if topic == CLOCK.name or topic.startswith('/sim/done/') else DATA_QOS
            msg_class = message_class(msgtypes[topic])
            self.publishers[topic] = self._node(publisher).create_publisher(msg_class, topic, qos)
            for subscriber in subscribers:
                self._node(subscriber).create_subscription(msg_class, topic, self._take, qos, raw=True)

    def _node(self, name):
        if name not in self.nodes:
            self.nodes[name] = Node(f'floor_{name}')
            self.executor.add_node(self.nodes[name])
        return self.nodes[name]

    def connect(self, timeout_s=30.0):
        """Wait until every publisher has all its subscribers (discovery)."""
        deadline = time.monotonic() + timeout_s
        while any(self.publishers[topic].get_subscription_count() < count
                  for topic, count in self.expected_per_topic.items()):
            if time.monotonic() > deadline:
                raise SystemExit('the floor graph did not connect within 30 s')
            self.executor.spin_once(timeout_sec=0.05)

    def run(self, ticks):
        """Publish ``ticks`` ticks, each after the last of the previous one was taken; wall time per tick."""
        self.tick, self.last_tick = 0, ticks
        self.finished = Future()
        started = time.perf_counter()
        self._publish_next_tick()
        self.executor.spin_until_future_complete(self.finished, timeout_sec=600.0)
        if not self.finished.done():
            raise SystemExit('the floor graph stalled')
        return (time.perf_counter() - started) / ticks

    def _publish_next_tick(self):
        self.tick += 1
        if self.tick > self.last_tick:
            self.finished.set_result(True)
            return
        publishes = [topic for topic, (per_tick, _) in self.traffic.items()
                     for _ in range(int(self.tick * per_tick) - int((self.tick - 1) * per_tick))]
        self.due = sum(self.expected_per_topic[topic] for topic in publishes)
        self.taken = 0
        for topic in publishes:
            self.publishers[topic].publish(self.traffic[topic][1])
        if self.due == 0:
            self._publish_next_tick()

    def _take(self, _):
        self.taken += 1
        if self.taken == self.due:
            self._publish_next_tick()

    def destroy(self):
        self.executor.shutdown()
        for node in self.nodes.values():
            node.destroy_node()


def handshake_fan_out(cores):
    """done topic -> (node, the nodes that read it): upstream nodes, the recorder (all), the clock."""
    readers = {core.name: [] for core in cores}
    names = set(readers)
    for core in cores:
        for upstream, _ in core.upstream:
            if upstream in names:
                readers[upstream].append(core.name)
    readers['recorder'] = ['clock']
    for name in [core.name for core in cores]:
        readers[name].append('recorder')
        if any(core.name == name and core.ends_run for core in cores):
            readers[name].append('clock')
    return {done_topic(name): (name, subscribers) for name, subscribers in readers.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--sim-s', type=float, default=800.0, help='sim time of the direct-mode baseline run')
    parser.add_argument('--ticks', type=int, default=4000, help='ticks of each traffic replay')
    args = parser.parse_args()
    load_before = current_load()
    with tempfile.TemporaryDirectory(prefix='bench_dds_floor_') as folder:
        direct_s, direct_ticks, data = direct_baseline(args.sim_s, Path(folder))
    cores = build_cores(graph_config(load_effect_config(ROOT / 'config/truth/nominal.yaml'), seed=1))
    topics = graph_topics(cores)
    data_fan_out, msgtypes = {}, {}
    for name, (msgtype, publisher, subscribers) in topics.items():
        wire = SAMPLE_BLOCKS.get(name)
        wire_name, wire_type = (wire.name, wire.msgtype) if wire else (name, msgtype)
        if publisher is not None and wire_name in data:
            data_fan_out[wire_name] = (publisher, [*subscribers, 'recorder'])
            msgtypes[wire_name] = wire_type
    # The documents and the rare parameter events are not per-tick traffic of the graph's topics.
    data = {topic: payload for topic, payload in data.items() if topic in data_fan_out}
    done_fan_out = handshake_fan_out(cores)
    msgtypes.update((topic, 'std_msgs/msg/String') for topic in done_fan_out)
    handshake = {topic: (1.0, serialize_message(String(data=DONE_REPORT))) for topic in done_fan_out}
    say(f'alignment graph, nominal truth; {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}')
    say(f'direct mode: {direct_ticks} ticks in {direct_s * direct_ticks:.1f} s wall = {direct_s * 1e3:.2f} ms per '
        f'tick (start-up included)')
    rows = []
    say(f'{"traffic":<10} {"publishes":>9} {"deliveries":>10} {"ms/tick":>8} {"x direct tick":>13}')
    with claimed_ros_domain():
        rclpy.init()
        try:
            for label, traffic, fan_out in (('data', data, data_fan_out), ('handshake', handshake, done_fan_out),
                                            ('both', {**data, **handshake}, {**data_fan_out, **done_fan_out})):
                graph = TrafficGraph(traffic, fan_out, msgtypes)
                graph.connect()
                per_tick_s = graph.run(args.ticks)
                graph.destroy()
                publishes = sum(per_tick for per_tick, _ in traffic.values())
                deliveries = sum(per_tick * len(fan_out[topic][1]) for topic, (per_tick, _) in traffic.items())
                say(f'{label:<10} {publishes:>9.1f} {deliveries:>10.1f} {per_tick_s * 1e3:>8.3f} '
                    f'{per_tick_s / direct_s:>13.2f}')
                rows.append({'traffic': label, 'publishes_per_tick': publishes, 'deliveries_per_tick': deliveries,
                             'ms_per_tick': per_tick_s * 1e3, 'share_of_direct_tick': per_tick_s / direct_s})
        finally:
            rclpy.try_shutdown()
    say('x direct tick: the messages alone as a share of direct mode\'s whole tick; executor/direct can be no '
        'lower than 1 + the "both" figure while every message and report travels over DDS')
    write_results('dds_floor', {'arguments': vars(args), 'direct_ticks': direct_ticks,
                                'direct_wall_s': direct_s * direct_ticks, 'direct_ms_per_tick': direct_s * 1e3,
                                'replays': rows}, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    sys.exit(main())
