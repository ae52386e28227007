"""Per-topic digest of a bag: type, offered QoS, message count and the sha256 of every (log time, payload)
in the bag's log-time order; two bags are the same recording when their digests match topic by topic.

    .venv/bin/python bench/bag_digest.py BAG [BAG ...]      one line per topic and bag; topics that differ marked

The digest covers log times as well as bytes, so a message moved in time shows up as much as a changed one.
"""

import argparse
import sys
from pathlib import Path

from sofia_ros.bag.digest import topic_digests


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('bags', nargs='+', type=Path)
    args = parser.parse_args()
    digests = [topic_digests(path) for path in args.bags]
    same = True
    for topic in sorted(set().union(*digests)):
        rows = [digest.get(topic) for digest in digests]
        differs = any(row != rows[0] for row in rows)
        same = same and not differs
        for path, row in zip(args.bags, rows):
            text = 'absent' if row is None else f'{row[0]} latched={row[1]} n={row[2]} sha256={row[3][:16]}'
            print(f'{"*" if differs else " "} {topic:<26} {path.name:<16} {text}')
    print('identical' if same else 'differ (* marks the topics)')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
