"""Receive glove's live results: the smallest subscriber, for a robot controller to start from.

Run the tracker with a stream, then this (in any order; start this first and give the
tracker ``--stream-wait 10`` to get every frame from the first)::

    glove track realsense --db grasp20.h5 --stream tcp://127.0.0.1:5555
    python examples/subscribe.py tcp://127.0.0.1:5555

Each message has two parts: the topic (``glove/hand`` from ``glove track``,
``glove/fingertips`` from ``glove fingertips detect --stream``) and the frame's record
as JSON, the same object as a line of ``poses.jsonl`` (docs/conventions.md). Needs only
pyzmq (``pip install pyzmq``).
"""

import argparse
import json

import zmq


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url", nargs="?", default="tcp://127.0.0.1:5555")
    parser.add_argument("--count", type=int, help="stop after this many messages")
    args = parser.parse_args()

    socket = zmq.Context().socket(zmq.SUB)
    socket.setsockopt(zmq.SUBSCRIBE, b"glove/")  # every topic; b"glove/hand" for poses only
    socket.connect(args.url)
    received = 0
    while args.count is None or received < args.count:
        topic, payload = socket.recv_multipart()
        record = json.loads(payload)
        received += 1
        if topic == b"glove/hand" and record["hand_found"]:
            x, y, z = record["translation_m"]  # the wrist, camera frame, metres
            print(f"frame {record['frame']}: wrist at ({x:.3f}, {y:.3f}, {z:.3f}) m, "
                  f"confidence {record['confidence']:.2f}", flush=True)  # fmt: skip
        elif topic == b"glove/hand":
            print(f"frame {record['frame']}: no hand", flush=True)
        else:
            tips = [tip.get("finger") for tip in record["fingertips"]]
            print(f"frame {record['frame']}: fingertips {tips}", flush=True)


if __name__ == "__main__":
    main()
