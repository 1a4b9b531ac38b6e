"""The walk of `mmsnap fuse`'s parsed arguments through the package.

Run `mmsnap fuse REC --bounds=-2,1.6,0,3.6 -o OUT` in this process with a
profile hook; a call is on the walk when one of its arguments carries the
parsed arguments: the argparse Namespace, an options object built from it
(one of CLASSES), a dict holding one of the
fusion's option keys, or a keyword argument named as one (mode, robust,
bounds, walls, ...); methods of the options objects themselves are left out. Files visited: the distinct package files of those
calls; the walk's steps: each such function once, at its first call; climbs:
consecutive steps whose file sits in a higher layer than the one before (the layers of tools/check_structure.py: factors <
data, errors, _*.py < evaluation < fusion, calibration, tracking, radar, sim
< io < app). Usage: python tools/argument_walk.py REC.h5 OUT.h5 (run from the checkout
whose code is walked, with it first on PYTHONPATH).

With --calibrate (python tools/argument_walk.py --calibrate REC.h5): the walk
of the recording through calibrate_recording instead: the recording read
(io.read_recording, not walked), then calibrate_recording(rec) with the
hook; a call is on the walk when one of its arguments is the recording or
its data (a Recording, NodeData or Detections, or a tuple, list or dict
holding one); their own methods are left out. Files and climbs as above."""
import argparse, contextlib, io, sys
from pathlib import Path

KEYS = {"mode", "robust", "options", "bounds", "static_bounds", "in_front", "walls", "body_m",
        "prior", "solver", "covariance", "gate_probability", "source", "motion_check"}
#: Keyword arguments that are the fusion's options themselves (80ec03d passed them loose).
LOOSE = {"mode", "robust", "bounds", "static_bounds", "in_front", "walls", "body_m",
         "motion_check"}
SUFFIX = ("Options", "Config", "Check", "Calibration", "Bounds")
OTHER = {"LearnedWalls", "StoredCalibration", "Namespace"}
LAYER = {"factors": 0, "data": 1, "errors": 1, "evaluation": 2, "fusion": 3, "calibration": 3,
         "tracking": 3, "radar": 3, "sim": 3, "io": 4, "app": 5}


#: The classes that hold `mmsnap fuse`'s options, old and new.
CLASSES = {"Namespace", "FusionOptions", "RobustOptions", "NetworkCalibration",
           "StoredCalibration", "RoomBounds", "FusionConfig", "AssociationOptions",
           "MotionCheck", "SplitCheck", "CoverageCheck", "RoomCheck", "LearnedWalls",
           "DuplicateCheck"}


def carries(v) -> bool:
    if type(v).__name__ in CLASSES:
        return True
    if CALIBRATE:  # the recording's data, also in a container
        held = list(v.values()) if isinstance(v, dict) else v if isinstance(v, (tuple, list)) \
            else ()
        return any(type(x).__name__ in CLASSES for x in held[:50])
    return isinstance(v, dict) and any(isinstance(k, str) and k in KEYS for k in v)


CALIBRATE = sys.argv[1] == "--calibrate"


def layer(path: str) -> int:
    rel = path.split("mmsnap_graph/")[-1] if "mmsnap_graph/" in path else "factors/x"
    top = rel.split("/")[0].removesuffix(".py")
    return LAYER.get(top, 1)  # _atomic.py, _validation.py, ...


walk = []


def hook(frame, event, arg):
    if event != "call":
        return
    f = frame.f_code.co_filename
    if "mmsnap_graph/" not in f and "/factors/" not in f:
        return
    code = frame.f_code
    names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount
                             + bool(code.co_flags & 4) + bool(code.co_flags & 8)]
    loc = frame.f_locals
    # Methods of the options objects themselves (their validation, lookups) are not the walk.
    if names and names[0] == "self" and carries(loc.get("self")):
        return
    # A loose option keyword (old code: bounds=, walls=, mode=, ...) carries them too.
    if any(n in LOOSE and loc.get(n) is not None and loc.get(n) is not False for n in names):
        walk.append((f, code.co_name))
        return
    vals = [loc.get(n) for n in names]
    vals += [x for n in names if isinstance(loc.get(n), (tuple, dict)) for x in
             (loc[n].values() if isinstance(loc[n], dict) else loc[n])]
    if any(carries(v) for v in vals):
        walk.append((f, code.co_name))


if CALIBRATE:
    import warnings
    from mmsnap_graph.calibration import calibrate_recording
    from mmsnap_graph.io import read_recording

    recording = read_recording(sys.argv[2], load_cubes=False)
    CLASSES, KEYS, LOOSE = {"Recording", "NodeData", "Detections"}, set(), set()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sys.setprofile(hook)
        cal = calibrate_recording(recording)
        sys.setprofile(None)
    print(f"calibrate_recording: method {cal.method}, success {cal.success}")
else:
    from mmsnap_graph.app.cli import main
    sys.setprofile(hook)
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["fuse", sys.argv[1], "--bounds=-2,1.6,0,3.6", "-o", sys.argv[2],
                     "--overwrite", "--no-progress", "--max-flagged", "1"])
    sys.setprofile(None)
    assert code == 0, code
files = sorted({f.split("mmsnap_graph/")[-1] for f, _ in walk})
# The walk's steps: each function once, at its first call (windows repeat the same steps).
steps = list(dict.fromkeys(walk))
climbs = sum(layer(b[0]) > layer(a[0]) for a, b in zip(steps, steps[1:]))
print(f"calls on the walk {len(walk)}, functions {len(steps)}, files visited {len(files)}, "
      f"climbs {climbs}")
for f in files:
    print("  ", f)
