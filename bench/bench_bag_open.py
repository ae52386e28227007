"""Benchmark: what a one-shot command pays to open a campaign bag, with ruamel's C YAML loader and without.

rosbags parses every bag's metadata.yaml, and each topic's QoS profiles inside it, with ruamel.yaml; so
does its writer when it adds a topic and closes the bag. ruamel.yaml.clib (requirements.txt) gives ruamel
its C loader and emitter. Each figure is one fresh process (imports done, nothing cached: what `sofia
compare`, a campaign's result or a test pays once), pure and C alternating, the best of ``--repeats``:

- open: `with BagReader(bag)` (metadata, summary CRC, rosbags' reader);
- result: alignment.result_from_bag (what every campaign run reads back for its summary);
- decode: compare.observations.decode_observations (compare's reading of the bag);
- write: a BagWriter with the bag's 30 topics, one message each, closed (metadata.yaml written).

The bag is a reduced alignment (2 repetitions, 1 verification, seed 3, nominal truth, direct mode,
1249 s of flight), recorded in a temporary directory unless one is given.

Run: .venv/bin/python bench/bench_bag_open.py [BAG] [--repeats N]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/bag_open.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

#: One measurement in a fresh interpreter: argv = loader ('pure' or 'c'), step, bag, scratch folder.
_MEASURE = '''
import sys, time
import ruamel.yaml.main
loader, step, bag, scratch = sys.argv[1:]
if loader == 'pure':
    ruamel.yaml.main.CParser = ruamel.yaml.main.CEmitter = None
elif ruamel.yaml.main.CParser is None:
    raise SystemExit('ruamel.yaml.clib is not installed: scripts/setup-venv installs it')
from pathlib import Path
from sofia_ros.bag import BagReader, BagWriter
from sofia_ros.campaigns.alignment import result_from_bag
from sofia_ros.compare.observations import decode_observations
with BagReader(bag) as reader:
    topics = [(topic.name, topic.msgtype) for topic in reader.topics]
    names = [name for name, _ in topics]
    first = reader.messages_by_topic(*names, raw=tuple(names)) if step == 'write' else {}
started = time.perf_counter()
if step == 'open':
    with BagReader(bag):
        pass
elif step == 'result':
    result_from_bag(bag)
elif step == 'decode':
    decode_observations(bag)
else:
    with BagWriter(Path(scratch) / 'copy') as writer:
        for name, msgtype in topics:
            writer.add_topic(name, msgtype)
            stamps_ns, payloads = first[name]
            if len(payloads):
                writer.write_raw(name, payloads[0], int(stamps_ns[0]))
print(time.perf_counter() - started)
'''

STEPS = ('open', 'result', 'decode', 'write')


def _record_bag(folder: Path) -> Path:
    """The reduced alignment (config/plans/alignment-reduced.yaml) of the nominal truth, seed 3, in ``folder``."""
    from sofia_ros.campaigns.registry import campaign_named
    from sofia_ros.config import load_effect_config

    alignment = campaign_named('alignment')
    truth = load_effect_config(ROOT / 'config' / 'truth' / 'nominal.yaml')
    return alignment.run(truth, seed=3, bag_path=folder / 'bag', plan=alignment.plan('reduced'), mode='direct').bag_path


def _seconds(loader: str, step: str, bag: Path, scratch: Path) -> float:
    shutil.rmtree(scratch / 'copy', ignore_errors=True)  # the write step's bag of the previous figure
    done = subprocess.run([sys.executable, '-c', _MEASURE, loader, step, str(bag), str(scratch)],
                          capture_output=True, text=True, check=False, cwd=ROOT)
    if done.returncode:
        last_line = (done.stderr.strip().splitlines() or ['no message'])[-1]  # the error, not its traceback
        raise SystemExit(f'bench_bag_open: the {loader} {step} measurement failed: {last_line}')
    return float(done.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('bag', nargs='?', type=Path)
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args()
    load_before = current_load()
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        bag = args.bag or _record_bag(folder)
        best = {(loader, step): float('inf') for loader in ('pure', 'c') for step in STEPS}
        for _ in range(args.repeats):
            for step in STEPS:
                for loader in ('pure', 'c'):
                    best[loader, step] = min(best[loader, step], _seconds(loader, step, bag, folder))
    say(f'bag: {args.bag or "a reduced alignment (seed 3, 1249 s), recorded for this run"}; '
        f'fresh process per figure, best of {args.repeats}, pure and C alternating')
    say(f'{"step":<8} {"pure ruamel (s)":>16} {"C loader (s)":>13} {"ratio":>6}')
    rows = []
    for step in STEPS:
        pure, fast = best['pure', step], best['c', step]
        rows.append({'step': step, 'pure_s': pure, 'c_s': fast, 'ratio': fast / pure})
        say(f'{step:<8} {pure:>16.3f} {fast:>13.3f} {fast / pure:>6.2f}')
    write_results('bag_open', {'bag': str(args.bag) if args.bag else None, 'repeats': args.repeats, 'rows': rows},
                  TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
