"""``mmsnap batch`` (mmsnap_graph/app/commands/batch.py): its usage errors (the runs
themselves: tests/app/test_batch.py)."""

from __future__ import annotations

import pytest

from _services import TcpService
from mmsnap_graph.app.cli import main


@pytest.mark.parametrize("argv, match", [
    (["--steps", "fuse,process"], "--steps"),
    (["--steps", "fly"], "--steps"),
    (["--workers", "0"], "--workers must be between 1 and"),
])
def test_cli_usage_errors_exit_2_with_one_line(recording_b_file, capsys, argv, match):
    assert main(["batch", str(recording_b_file.parent / "*.h5"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mmsnap batch: error: ") and match in err[0]


def test_workers_and_scheduler_exclude_each_other_in_argparse(recording_b_file, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["batch", str(recording_b_file.parent / "*.h5"), "--workers", "2",
              "--scheduler", "tcp://127.0.0.1:1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --scheduler: not allowed with argument --workers" in err


def test_cli_no_match_and_bad_int(tmp_path, capsys):
    assert main(["batch", str(tmp_path / "*.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no recording matches" in err[0]
    with pytest.raises(SystemExit) as exc:
        main(["batch", "x.h5", "--workers", "two"])
    assert exc.value.code == 2
    assert "invalid int value: 'two'" in capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize("workers", ["1000000", "0", "-3"])
def test_a_worker_count_beyond_the_machine_is_a_usage_error(tmp_path, capsys, workers):
    from mmsnap_graph.app.cli import main

    rec = tmp_path / "rec.h5"
    rec.write_bytes(b"")  # never opened: the option is refused first
    assert main(["batch", str(rec), "--workers", workers, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--workers must be between 1 and" in err and err.count("\n") == 1


@pytest.mark.parametrize("banner, match", [
    (None, "no Dask scheduler answered within 1 s"),
    (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", "not a Dask scheduler"),
    (b"SSH-2.0-OpenSSH_9.6\r\n", "not a Dask scheduler"),
    (b"", None),  # a port nothing listens on any more: handled below
])
def test_a_scheduler_address_that_is_not_dask_fails_fast(tmp_path, capsys, monkeypatch,
                                                          banner, match):
    import time
    from mmsnap_graph.app.commands import batch

    monkeypatch.setattr(batch, "CONNECT_TIMEOUT_S", 1.0)
    rec = tmp_path / "rec.h5"
    rec.write_bytes(b"")
    service = TcpService(banner)
    if banner == b"":
        service.close()  # a closed port: connection refused
        match = "cannot connect"
    try:
        start = time.monotonic()
        code = main(["batch", str(rec), "--scheduler", f"tcp://127.0.0.1:{service.port}",
                     "--no-progress"])
        elapsed = time.monotonic() - start
    finally:
        service.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and match in err[0], err
    assert elapsed < 5.0


@pytest.mark.parametrize("address", ["tls://127.0.0.1:8786", "ucx://127.0.0.1:8786",
                                     "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "inproc://x"])
def test_scheduler_addresses_of_other_schemes_are_usage_errors(tmp_path, capsys, address):
    rec = tmp_path / "rec.h5"
    rec.write_bytes(b"")
    assert main(["batch", str(rec), "--scheduler", address, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scheduler" in err[0], err


def test_batch_says_a_failed_covariance_self_check_loudly(calibrated_c_file, tmp_path, capsys,
                                                          monkeypatch):
    """The fuse step's self-check (as `mmsnap fuse`'s) is in each summary's
    counts, and a failed one (sigmas 0.3x the data's) is a loud line on
    stderr naming the recording; not with --no-self-check."""
    import concurrent.futures
    import contextlib
    import json
    import shutil

    import h5py
    import numpy as np

    import mmsnap_graph.app.batch as batch_module
    from mmsnap_graph.io.noise import read_noise

    @contextlib.contextmanager
    def threads(n_workers):  # no Dask cluster: any Executor runs the batch
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            yield pool

    monkeypatch.setattr(batch_module, "local_client", threads)
    rec = shutil.copy(calibrated_c_file, tmp_path / "rec.h5")
    before = read_noise(rec).per_node
    with h5py.File(rec, "r+") as f:  # the stored sigmas 0.3x the data's
        f["noise"]["sigmas"][...] = 0.3 * f["noise"]["sigmas"][...]
    n = next(iter(before))
    np.testing.assert_allclose(read_noise(rec).per_node[n].sigmas, 0.3 * before[n].sigmas)
    argv = ["batch", str(rec), "--steps", "fuse", "--no-progress", "--json", "--output-dir",
            str(tmp_path / "out")]
    assert main(argv) == 0
    cap = capsys.readouterr()
    (summary,) = json.loads(cap.out)
    assert summary["counts"]["self_check"] == "over-confident"
    assert f"mmsnap batch: {rec}: warning: the fused covariances are over-confident" in cap.err
    assert main([*argv, "--overwrite", "--no-self-check"]) == 0
    assert "warning" not in capsys.readouterr().err
