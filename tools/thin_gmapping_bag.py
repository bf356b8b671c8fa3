#!/usr/bin/env python3
"""thin_gmapping_bag.py RAW.bag OUT.bag: keep a small bag of what live gmapping made in a replay
(`DEMO_KEEP_GMAPPING=1 make demo` records RAW.bag: /clock, /tf, /<robot>/map), for `make demo`
on machines without gmapping: each robot's map at most every MAP_PERIOD s of bag time (and its
last one), each transform (parent, child) at most every TF_PERIOD s; no /clock (`rosbag play
--clock` makes it); bz2."""
import sys

import rosbag

MAP_PERIOD = 4.0
TF_PERIOD = 0.25


def main(raw, out):
    last = {}
    final_maps = {}

    def due(key, t, period):
        if t - last.get(key, -1e18) >= period:
            last[key] = t
            return True
        return False

    kept = 0
    with rosbag.Bag(raw) as src, rosbag.Bag(out, 'w', compression='bz2') as dst:
        for topic, msg, t in src.read_messages():
            s = t.to_sec()
            if topic == '/tf':
                msg.transforms = [x for x in msg.transforms
                                  if due((x.header.frame_id, x.child_frame_id), s, TF_PERIOD)]
                keep = bool(msg.transforms)
            elif topic.endswith('/map'):
                final_maps[topic] = (msg, t)
                keep = due(topic, s, MAP_PERIOD)
                if keep:
                    final_maps.pop(topic)
            else:
                keep = False
            if keep:
                dst.write(topic, msg, t)
                kept += 1
        for topic, (msg, t) in final_maps.items():
            dst.write(topic, msg, t)
            kept += 1
    print('thin_gmapping_bag: %d messages kept: %s' % (kept, out))


if __name__ == '__main__':
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
