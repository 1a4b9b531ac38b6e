"""Stand-ins for real TI data, made from the simulator (issue 14), and the
script that writes the small samples in data/ti/:

    python tests/ti_samples.py      # rewrites data/ti/*.bin and *.csv

Each radar's simulated 2D point cloud is lifted into 3D: every point gets a
height above the floor, then it is expressed in the frame of a sensor mounted
at ``height_m`` and tilted down by ``tilt_rad``, with the 3D radial speed of a
horizontally moving scatterer. Projecting back (factors.projection) must give
the simulated 2D points again.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from mmsnap_graph.sim import SimulationOptions

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from factors.models import detection_to_local  # noqa: E402
from factors.projection import level_to_sensor, sensor_to_room  # noqa: E402
from mmsnap_graph.sim import simulate_recording  # noqa: E402
from ti_encode import encode_oob_frame  # noqa: E402

from _shared import TI_DATA as DATA  # noqa: E402
#: node -> (mounting height m, down tilt rad) of the samples.
MOUNTS = {"S1": (0.8, np.deg2rad(5.0)), "S2": (1.2, np.deg2rad(15.0))}
FRAME_PERIOD_S = 0.05
#: Frames of the point-cloud samples: 5 s at 20 fps, enough for ``mmsnap
#: calibrate`` to match the two nodes' tracks (docs/TI.md's walkthrough).
SAMPLE_FRAMES = 100


def simulated(n_frames=SAMPLE_FRAMES, seed=1, trajectory="straight"):
    """A simulated recording (point clouds) at 20 fps."""
    return simulate_recording("C", trajectory,
                              SimulationOptions(physics=None, frame_period_s=FRAME_PERIOD_S),
                              levels=["point_cloud"], n_frames=n_frames, seed=seed)


def lift(det, height_m, tilt_rad, seed):
    """2D detections -> sensor-frame ``(xyz (K, 3), doppler_3d (K,))``."""
    rng = np.random.default_rng(seed)
    local = detection_to_local(det.range_m, det.omega_rad)
    z_floor = rng.uniform(0.3, 1.7, len(det))
    level = np.column_stack([local, z_floor - height_m])
    xyz = level_to_sensor(level, tilt_rad)
    r3 = np.linalg.norm(xyz, axis=1)
    return xyz, det.doppler_mps * det.range_m / r3


def write_uart_log(path, det, height_m, tilt_rad, seed, first_frame=1):
    xyz, dop = lift(det, height_m, tilt_rad, seed)
    frames = np.unique(det.frame)
    packets = []
    for f in range(int(frames.min()), int(frames.max()) + 1):
        rows = det.frame == f
        packets.append(encode_oob_frame(f + first_frame, xyz[rows], dop[rows], det.snr_db[rows],
                                        np.full(rows.sum(), 45.0)))
    Path(path).write_bytes(b"".join(packets))


def table_rows(rec, *, room: bool, seed=0):
    """Rows of a CSV with every node (node column); sensor or room frame."""
    import pandas as pd
    parts = []
    for k, (name, node) in enumerate(rec.nodes.items()):
        height, tilt = MOUNTS[name]
        det = node.point_cloud
        xyz, dop = lift(det, height, tilt, seed + k)
        if room:
            xyz = sensor_to_room(xyz, rec.truth.node_poses[name], height, tilt)
        parts.append(pd.DataFrame({"node": name, "frame": det.frame,
                                   "time_s": 1700000000.0 + det.frame * FRAME_PERIOD_S,
                                   "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                   "doppler": dop, "snr": det.snr_db}))
    return pd.concat(parts, ignore_index=True)


#: The .cfg of the small DCA1000 sample: sub-frame 0 fires TX0, TX2 (32
#: samples, 4 loops), sub-frame 1 fires TX0, TX2, TX1 (64 samples, 8 loops).
DCA_CFG = """\
% Small AWR1843BOOST advanced frame for the DCA1000 sample (data/ti/dca1000_small.bin)
sensorStop
flushCfg
dfeDataOutputMode 3
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 10 3 25 0 0 50 1 32 2000 0 0 30
profileCfg 1 77 10 3 40 0 0 50 1 64 2000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
chirpCfg 2 2 1 0 0 0 0 1
chirpCfg 3 3 1 0 0 0 0 4
chirpCfg 4 4 1 0 0 0 0 2
advFrameCfg 2 0 3 1 0
subFrameCfg 0 0 0 2 4 25 0 1 1 25
subFrameCfg 1 0 2 3 8 25 0 1 1 25
lvdsStreamCfg -1 0 1 0
sensorStart
"""
#: int16 ADC counts per unit of the simulator's cube.
DCA_SCALE = 100.0


def dca_sample_cubes(n_frames=3, seed=1):
    """Node S1's simulated cubes of each sub-frame (int16 counts as complex).

    A random walk whose radial speed (0.7-0.9 m/s) keeps the target out of
    the zero-Doppler bin, which static clutter removal empties: with only 8
    loops, the straight walk's first frames (|Doppler| < 0.1 m/s) left
    ``mmsnap process`` no point at all."""
    from mmsnap_graph.io.ti.cfg import parse_ti_cfg
    ti = parse_ti_cfg(DCA_CFG, board="AWR1843BOOST")
    cubes = []
    for cfg in ti.configs:
        rec = simulate_recording("C", "random", SimulationOptions(physics=None, radar=cfg),
                                 levels=["cube"], n_frames=n_frames, seed=seed)
        cube = rec.nodes["S1"].cube * DCA_SCALE
        cubes.append(np.round(cube.real) + 1j * np.round(cube.imag))
    return ti, cubes


def write_dca_sample(out_dir: Path) -> None:
    from mmsnap_graph.io import write_dca1000_bin
    from mmsnap_graph.io.ti.dca1000 import frame_bytes
    (out_dir / "dca1000_small.cfg").write_text(DCA_CFG)
    ti, cubes = dca_sample_cubes()
    frames = []
    for k, (cfg, cube) in enumerate(zip(ti.configs, cubes)):
        part = out_dir / f"_sub{k}.bin"
        write_dca1000_bin(part, cube, cfg)
        raw, size = part.read_bytes(), frame_bytes(cfg)
        part.unlink()
        frames.append([raw[f * size:(f + 1) * size] for f in range(cube.shape[0])])
    (out_dir / "dca1000_small.bin").write_bytes(b"".join(b"".join(parts)
                                                         for parts in zip(*frames)))


#: The .cfg of the fast-target sample (data/ti/dca1000_fast.bin): one
#: profile, TX0, TX2, TX1 in turn (TDM-MIMO), 16 loops of 150 us: the
#: unambiguous speed is +-6.41 m/s.
FAST_CFG = """\
% AWR1843BOOST, TDM-MIMO TX0, TX2, TX1, 16 loops: a target faster than the unambiguous speed
sensorStop
flushCfg
dfeDataOutputMode 1
channelCfg 15 7 0
adcCfg 2 1
adcbufCfg -1 0 1 1 1
profileCfg 0 77 10 3 40 0 0 50 1 64 2000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
chirpCfg 1 1 0 0 0 0 0 4
chirpCfg 2 2 0 0 0 0 0 2
frameCfg 0 2 16 0 50 1 0
lvdsStreamCfg -1 0 1 0
sensorStart
"""
#: The fast target: range at frame 0 (m), azimuth (rad), radial speed (m/s,
#: approaching), one point scatterer moving straight at the radar.
FAST_TARGET = (4.0, 0.3, -8.5)


def fast_sample_cubes(n_frames=3, seed=0):
    """Node S1's cubes of the fast target (int16 counts as complex)."""
    from mmsnap_graph.io.ti.cfg import parse_ti_cfg
    from mmsnap_graph.sim.cube import scatterer_amplitude, synthesize_cube
    cfg = parse_ti_cfg(FAST_CFG, board="AWR1843BOOST").configs[0]
    rng = np.random.default_rng(seed)
    r0, azimuth, speed = FAST_TARGET
    cubes = []
    for k in range(n_frames):
        r = r0 + speed * cfg.frame_period_s * k
        p = np.array([[r * np.sin(azimuth), r * np.cos(azimuth)]])
        cube = synthesize_cube(cfg, p, speed * p / r, scatterer_amplitude(cfg, 1.0, r),
                               rng=rng) * DCA_SCALE
        cubes.append(np.round(cube.real) + 1j * np.round(cube.imag))
    return cfg, np.stack(cubes)


def write_fast_sample(out_dir: Path) -> None:
    from mmsnap_graph.io import write_dca1000_bin
    (out_dir / "dca1000_fast.cfg").write_text(FAST_CFG)
    cfg, cubes = fast_sample_cubes()
    write_dca1000_bin(out_dir / "dca1000_fast.bin", cubes, cfg)


def studio_json(cfg_text: str = FAST_CFG) -> dict:
    """An mmWave Studio JSON export (the fields ``read_studio_json`` reads) of a
    legacy-frame ``.cfg`` whose chirps each fire one transmitter."""
    words = {line.split()[0]: line.split()[1:] for line in cfg_text.splitlines()
             if line.strip() and not line.startswith("%") and line.split()[0] != "chirpCfg"}
    num = lambda w: int(w) if float(w) == int(float(w)) else float(w)  # noqa: E731
    p = [num(w) for w in words["profileCfg"]]
    chirps = [[int(w) for w in line.split()[1:]] for line in cfg_text.splitlines()
              if line.startswith("chirpCfg")]
    f = [num(w) for w in words["frameCfg"]]
    rx, tx, _ = (int(w) for w in words["channelCfg"])
    bits, fmt = (int(w) for w in words["adcCfg"])
    profile = {"profileId": p[0], "startFreqConst_GHz": p[1], "idleTimeConst_usec": p[2],
               "adcStartTimeConst_usec": p[3], "rampEndTime_usec": p[4],
               "freqSlopeConst_MHz_usec": p[7], "txStartTime_usec": p[8],
               "numAdcSamples": p[9], "digOutSampleRate": p[10], "rxGain_dB": hex(p[13])}
    rf = {"waveformType": "legacyFrameChirp",
          "rlChanCfg_t": {"rxChannelEn": hex(rx), "txChannelEn": hex(tx), "cascading": 0},
          "rlAdcOutCfg_t": {"fmt": {"b2AdcBits": bits, "b2AdcOutFmt": fmt}},
          "rlProfiles": [{"rlProfileCfg_t": profile}],
          "rlChirps": [{"rlChirpCfg_t": {"chirpStartIdx": c[0], "chirpEndIdx": c[1],
                                         "profileId": c[2], "startFreqVar_MHz": 0.0,
                                         "freqSlopeVar_KHz_usec": 0.0, "idleTimeVar_usec": 0.0,
                                         "adcStartTimeVar_usec": 0.0, "txEnable": hex(c[7])}}
                       for c in chirps],
          "rlFrameCfg_t": {"chirpStartIdx": f[0], "chirpEndIdx": f[1], "numLoops": f[2],
                           "numFrames": f[3], "framePeriodicity_msec": f[4]}}
    return {"configGenerator": {"createdBy": "tests/ti_samples.py"},
            "mmWaveDevices": [{"mmWaveDeviceId": 0, "rfConfig": rf}]}


def main(out_dir: Path = DATA) -> None:
    out_dir = Path(out_dir)
    rec = simulated()
    for k, (name, (height, tilt)) in enumerate(MOUNTS.items()):
        write_uart_log(out_dir / f"oob_uart_{name}.bin", rec.nodes[name].point_cloud, height,
                       tilt, seed=k)
    table_rows(rec, room=False).to_csv(out_dir / "points_sensor_frame.csv", index=False,
                                       float_format="%.6f")
    table_rows(rec, room=True).to_csv(out_dir / "points_room_frame.csv", index=False,
                                      float_format="%.6f")
    write_dca_sample(out_dir)
    write_fast_sample(out_dir)
    (out_dir / "dca1000_fast.mmwave.json").write_text(json.dumps(studio_json(), indent=2) + "\n")


if __name__ == "__main__":
    main()
