"""Convert the two DarkSZChao recordings (pickles) into point tables (CSV).

Run: ``python data/real/darksz/make_tables.py SOURCE_DIR [--out DIR]`` where
SOURCE_DIR holds the recorder's files (README.md here lists them with their
md5). Standard library and NumPy only; the output is the same byte for byte
on every run.

What it does, per recording and radar (``IWR1843_Ori`` -> ``S1``,
``IWR1843_Side`` -> ``S2``; the ceiling radar ``IWR1843_Top`` looks down and
is left out):

- reads the pickle with an unpickler that accepts NumPy arrays, lists and
  dicts only (a pickle can run any code when loaded: never ``pickle.load`` a
  third-party file as it is);
- undoes the recorder's stacking exactly: each saved frame holds the radar's
  last 10 frames oldest first, so saved frame ``k + 1`` starts with the tail
  of saved frame ``k``; the points after the longest such overlap are the
  frame new in ``k + 1``. The 9 older frames of the first stack are recovered
  from the heads that later frames drop, so table frame ``f`` is the radar
  frame of saved frame ``f - 9``;
- writes every value with the precision it has (float16: the shortest
  decimal that reads back to the same float16); ``snr`` (0.1 dB) becomes
  ``snr_db``; ``time_s`` is the nominal ``frame / 20 fps`` (the recorder kept
  no time stamps), so that both radars share one frame clock on import.

Coordinates stay in the recorder's room frame (``mmsnap import table
--room-pose`` takes them back to each sensor's frame).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import io
import pickle
from pathlib import Path

import numpy as np

#: source pickle -> (output stem, md5 of the source)
RECORDINGS = {
    "multiple_tracking_Jun-05-16-07-02.pkl": ("multiple_tracking",
                                              "d6efdb9cabfe3e5cdcb3c118c2c57730"),
    "fall_detection_Jun-10-15-48-31.pkl": ("fall_detection", "99acedce541a1b7257f0a31b61060351"),
}
RADARS = {"IWR1843_Ori": "S1", "IWR1843_Side": "S2"}
FRAME_PERIOD_S = 0.05
STACK = 10
HEADER = "frame,time_s,x_m,y_m,z_m,doppler_mps,snr_db"

_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
}


class _ArraysOnly(pickle.Unpickler):
    """Builds NumPy arrays, lists and dicts; refuses every other class."""

    def find_class(self, module: str, name: str):
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"refusing {module}.{name}: only NumPy arrays, "
                                         "lists and dicts are loaded")
        return getattr(importlib.import_module(module), name)


def load_frames(path: Path, md5: str) -> list[dict]:
    data = path.read_bytes()
    digest = hashlib.md5(data).hexdigest()
    if digest != md5:
        raise SystemExit(f"{path}: md5 {digest}, expected {md5} (not the recording converted "
                         "here)")
    frames = _ArraysOnly(io.BytesIO(data)).load()
    if not isinstance(frames, list) or not all(isinstance(f, dict) for f in frames):
        raise SystemExit(f"{path}: expected a list of dicts")
    return frames


def _overlap(older: np.ndarray, newer: np.ndarray) -> int:
    """Length of the longest head of ``newer`` equal to a tail of ``older``."""
    a, b = older.view(np.uint16), newer.view(np.uint16)
    for m in range(min(len(a), len(b)), 0, -1):
        if np.array_equal(b[:m], a[len(a) - m:]):
            return m
    return 0


def destack(stacks: list[np.ndarray]) -> list[np.ndarray]:
    """Saved stacks -> the radar's own frames (oldest first, STACK - 1 older
    frames recovered from the first stack when the stacks agree)."""
    overlaps = [_overlap(a, b) for a, b in zip(stacks[:-1], stacks[1:])]
    frames = [b[m:] for b, m in zip(stacks[1:], overlaps)]
    heads = [a[:len(a) - m] for a, m in zip(stacks[:-1], overlaps)]
    first = stacks[0]
    older = heads[:STACK - 1]
    n_older = sum(len(h) for h in older)
    if len(older) == STACK - 1 and np.array_equal(
            np.concatenate(older).view(np.uint16) if n_older else first[:0].view(np.uint16),
            first[:n_older].view(np.uint16)):
        return list(older) + [first[n_older:]] + frames
    # Stacks that disagree: keep the whole first stack as one frame.
    return [np.zeros((0, first.shape[1]), first.dtype)] * (STACK - 1) + [first] + frames


def _text(values: np.ndarray) -> list[str]:
    return [str(v) for v in values]


def table_text(frames: list[np.ndarray]) -> str:
    lines = [HEADER]
    for f, points in enumerate(frames):
        if not len(points):
            continue
        if points.dtype != np.float16 or points.ndim != 2 or points.shape[1] != 5:
            raise SystemExit(f"frame {f}: expected (N, 5) float16 points, got {points.dtype} "
                             f"{points.shape}")
        cols = [_text(points[:, j]) for j in range(4)]
        snr = [repr(round(float(v) / 10.0, 4)) for v in points[:, 4]]
        t = f"{f * FRAME_PERIOD_S:.2f}"
        lines += [",".join((str(f), t, x, y, z, v, s))
                  for x, y, z, v, s in zip(*cols, snr)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("source", type=Path, help="folder holding the recorder's pickles")
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent,
                   help="output folder (default: this script's)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for source, (stem, md5) in RECORDINGS.items():
        saved = load_frames(args.source / source, md5)
        for radar, node in RADARS.items():
            frames = destack([np.asarray(s[radar]) for s in saved])
            path = args.out / f"{stem}_{node}.csv"
            path.write_text(table_text(frames))
            n = sum(len(f) for f in frames)
            print(f"{path.name}: {n} points in {len(frames)} frames "
                  f"({len(saved)} saved stacks)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
