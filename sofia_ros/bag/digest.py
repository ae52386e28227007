"""Per-topic digest of a bag: two bags are the same recording when their digests match topic by topic.

The digest covers log times as well as bytes, so a message moved in time shows up as much as a changed one.
"""

from __future__ import annotations

import hashlib

from sofia_ros.bag.reader import BagReader

__all__ = ['topic_digests']


def topic_digests(bag_path):
    """topic -> (msgtype, latched, count, sha256 hex) of the bag at ``bag_path``."""
    with BagReader(bag_path) as bag:
        latched = bag.latched_topics()
        hashes = {info.name: hashlib.sha256() for info in bag.topics}
        counts = dict.fromkeys(hashes, 0)
        for topic, stamp_ns, data in bag.raw_messages():
            hashes[topic].update(stamp_ns.to_bytes(8, 'little') + len(data).to_bytes(4, 'little'))
            hashes[topic].update(data)
            counts[topic] += 1
        return {info.name: (info.msgtype, info.name in latched, counts[info.name], hashes[info.name].hexdigest())
                for info in bag.topics}
