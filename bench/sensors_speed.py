"""Time the sensor models on 640×480 frames: synthetic RGB and mask corruption.

    .venv/bin/python bench/sensors_speed.py [--repeats 30]

Prints the median ms per call. glibc's allocator returns large numpy temporaries to the OS
after each frame; MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=268435456 in the
environment keeps them (see sensors/rgb.py) — compare both ways.
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np

from liquidtwin.sensors import MaskNoise, RGBParams, corrupt_mask, synth_rgb


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=30)
    args = p.parse_args(argv)
    rng = np.random.default_rng(0)
    H, W = 480, 640
    thick = np.zeros((H, W), np.float32)
    cv2.circle(thick, (320, 260), 60, 1.0, -1)
    thick = cv2.GaussianBlur(thick, (0, 0), 15) * 8.0
    mask = thick > 0.5
    labels = np.zeros((H, W), np.int32)
    cv2.rectangle(labels, (200, 150), (440, 420), 1, -1)
    params = RGBParams.sample(rng)
    out = {
        "synth_rgb_ms": _median_ms(lambda: synth_rgb(rng, liquid_thickness=thick, liquid_mask=mask, labels=labels,
                                                     object_colors=[(0.6, 0.3, 0.2)], params=params), args.repeats),
        "corrupt_mask_ms": _median_ms(lambda: corrupt_mask(mask, rng, MaskNoise()), args.repeats),
        "liquid_px": int(mask.sum()), "size": [W, H],
    }
    print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in out.items()}))
    return out


if __name__ == "__main__":
    main()
