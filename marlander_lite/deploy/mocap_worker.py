"""Child process that talks to the motion-capture system and prints one JSON line per frame.

Run as a script (``python mocap_worker.py KIND CFG_JSON``), never imported by the loop: the
``motioncapture`` extension holds Python's GIL while ``connect`` waits for a server (measured:
a thread calling ``motioncapture.connect("vicon", ...)`` with no server freezes every other
thread of the process), so the connection and the frame reading live in their own process,
which :class:`marlander_lite.deploy.pose_sources.MotionCaptureSource` can time out and kill.

Output lines (stdout):

* ``{"status": "connected"}`` once connected;
* ``{"status": "error", "message": ...}`` if connecting or reading fails, then the process exits;
* ``{"t": T, "b": {name: [x, y, z, qw, qx, qy, qz], ...}}`` per frame: ``T`` is
  ``time.monotonic()`` when the frame arrived (the same clock as the parent's on Linux/macOS/
  Windows), positions in metres, quaternions in motioncapture's order (w first). Occluded
  bodies are absent.

This file imports nothing from marlander_lite so that the child starts in a fraction of a second.
"""

from __future__ import annotations

import json
import sys
import time


def main(kind: str, cfg_json: str) -> int:
    try:
        import motioncapture

        cfg = {str(k): str(v) for k, v in json.loads(cfg_json).items()}
        mc = motioncapture.connect(kind, cfg)
    except Exception as error:  # report any failure to the parent, which raises it
        print(json.dumps({"status": "error", "message": f"{type(error).__name__}: {error}"}), flush=True)
        return 1
    print(json.dumps({"status": "connected"}), flush=True)
    try:
        while True:
            mc.waitForNextFrame()
            now = time.monotonic()
            bodies = {}
            for name, body in mc.rigidBodies.items():
                p, q = body.position, body.rotation
                bodies[name] = [float(p[0]), float(p[1]), float(p[2]), q.w, q.x, q.y, q.z]
            print(json.dumps({"t": now, "b": bodies}), flush=True)
    except (BrokenPipeError, KeyboardInterrupt):  # the parent went away or stopped us
        return 0
    except Exception as error:
        print(json.dumps({"status": "error", "message": f"{type(error).__name__}: {error}"}), flush=True)
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
