"""Cut the sample bag out of a recorded experiment: every topic, but only the first frames.

    .venv/bin/microball experiment --duration 20 --speed 1.5 --output /tmp/run
    .venv/bin/python bags/make_sample.py /tmp/run bags/paper_sample
    .venv/bin/microball analyze bags/paper_sample --json bags/paper_sample.expected.json

Messages are copied byte for byte with their times and QoS, and the metadata custom_data comes
along: the recorded node parameters, so `microball reprocess` works on the sample too, and the
recording platform's fingerprint ('microball.platform'), so reprocess and the tests know where
the sample must reproduce byte for byte and where only within tolerance (docs/design.md section 4).
Re-record on the machine the tests run on most (CI) to get byte identity there.
"""

import argparse
import sys

from microball_ros.io.bags.reader import open_bag
from microball_ros.io.bags.writer import BagWriter
from microball_ros.io.fingerprint import CUSTOM_DATA_KEY, from_custom_data

FRAME_TOPICS = ('/camera/image_raw', '/tracking/debug_image')


def main():
    """Copy the bag, keeping the first --frames messages of the image topics."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('source')
    parser.add_argument('output')
    parser.add_argument('--frames', type=int, default=15, help='image messages to keep')
    args = parser.parse_args()
    bag = open_bag(args.source)
    kept = dict.fromkeys(FRAME_TOPICS, 0)
    with BagWriter(args.output) as writer:
        writer.custom_data.update((bag.metadata or {}).get('custom_data') or {})
        for name, info in sorted(bag.topics.items()):
            writer.add_topic(name, info.type, info.qos_profiles_yaml)
        for message in bag.messages():
            if message.topic in kept:
                if kept[message.topic] >= args.frames:
                    continue
                kept[message.topic] += 1
            writer.write(message.topic, message.data, message.log_time_ns,
                         message.publish_time_ns)
    for line in open_bag(args.output).info_lines():
        print(line)
    platform = from_custom_data(open_bag(args.output).metadata.get('custom_data'))
    if platform is None:
        print(f'warning: {args.source} carries no platform fingerprint ({CUSTOM_DATA_KEY}); '
              'the sample can then only be checked within tolerance', file=sys.stderr)
    else:
        print(f"platform: {platform.get('key')} ({platform.get('cpu')}, numpy SIMD "
              f"{platform.get('numpy_simd')})")


if __name__ == '__main__':
    main()
