"""Pour a cup into a bowl and record it to MCAP (what ``liquidtwin demo`` does, in a script).

Builds the scene of :mod:`liquidtwin.scenes.pour` (a cup with ~175 ml tilts over a 16 cm
bowl), steps it, writes every 4th step to an MCAP file (foxglove.PointCloud on
``/particles``, object poses on ``/objects``, volumes on ``/volumes``) and prints the
liquid in cup and bowl. The whole pour is 624 steps; open the result with
``liquidtwin-viewer --mcap out/02_pour.mcap`` or in Foxglove.

    python examples/02_pour_demo.py --steps 624 --out out/02_pour.mcap
"""

import argparse

import torch

from liquidtwin.record import Recorder
from liquidtwin.scenes.pour import build_pour_scene, liquid_volumes
from liquidtwin.sim import step


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=624,
                        help="steps of 1/120 s (default: %(default)s, the whole pour)")
    parser.add_argument("--out", default="out/02_pour.mcap",
                        help="MCAP file to write (default: %(default)s)")
    args = parser.parse_args(argv)

    scene = build_pour_scene(seconds=args.steps / 120)
    state = scene.state
    with Recorder(args.out) as rec, torch.no_grad():
        rec.write_state(state, scene.names, liquid_volumes(scene.model, state, scene.containers))
        for i in range(scene.steps):
            state = step(scene.model, state, scene.poses[i])
            if (i + 1) % 4 == 0 or i + 1 == scene.steps:
                volumes = liquid_volumes(scene.model, state, scene.containers)
                rec.write_state(state, scene.names, volumes)

    volumes = liquid_volumes(scene.model, state, scene.containers)
    print(f"{state.x.shape[0]} particles, {scene.steps} steps, t = {state.t:.2f} s, "
          f"{rec.frames} frames -> {args.out}")
    print("  ".join(f"{name} {ml:.1f} ml" for name, ml in volumes.items()))
    return volumes


if __name__ == "__main__":
    main()
