"""Cut the sample bag out of a recorded experiment: every topic, but only the first frames.

    .venv/bin/microball experiment --duration 20 --speed 1.5 --output /tmp/run
    .venv/bin/python bags/make_sample.py /tmp/run bags/paper_sample
    .venv/bin/microball analyze bags/paper_sample --json bags/paper_sample.expected.json

Messages are copied byte for byte with their times and QoS, and the recorded node parameters
(metadata custom_data) come along, so `microball reprocess` works on the sample too.
"""

import argparse

from microball_ros.io.bags.reader import open_bag
from microball_ros.io.bags.writer import BagWriter

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


if __name__ == '__main__':
    main()
