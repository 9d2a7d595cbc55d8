"""A --scheduler that is not a Dask scheduler, or never answers, ends in one line within the connect timeout."""

from __future__ import annotations

import http.server
import socket
import threading
import time

import pytest

pytest.importorskip("distributed")

from ifmi.cli import main  # noqa: E402
from ifmi.errors import InputError  # noqa: E402
from ifmi.runtime.local_workers import scheduler_client  # noqa: E402

# Seconds the tests give a scheduler; a process that waits longer than this plus its start-up hangs.
TIMEOUT_S = 1.0
# Start-up of the command (imports, reading the dataset) on a loaded machine, seconds.
STARTUP_ALLOWANCE_S = 60.0


class QuietHandler(http.server.BaseHTTPRequestHandler):
    """Answers HTTP (400 to Dask's bytes) without logging to stderr, which the tests read."""

    def log_message(self, format, *args):
        pass


@pytest.fixture
def http_address():
    """A loopback HTTP server (as a Dask dashboard would be), as a Dask address."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), QuietHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"tcp://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


@pytest.fixture
def silent_address():
    """A loopback listener that accepts connections and never sends a byte."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    listener.close()


@pytest.mark.slow
def test_an_http_server_is_refused_in_one_line(http_address):
    start = time.monotonic()
    with pytest.raises(InputError, match=r"^--scheduler: cannot connect to a Dask scheduler at "
                                         r"'tcp://127\.0\.0\.1:\d+': no Dask answer within 1 s .*"
                                         r"--connect-timeout SECONDS"):
        scheduler_client(http_address, connect_timeout_s=TIMEOUT_S)
    assert time.monotonic() - start < TIMEOUT_S + STARTUP_ALLOWANCE_S


@pytest.mark.slow
def test_a_listener_that_never_answers_is_refused_after_the_timeout(silent_address):
    start = time.monotonic()
    with pytest.raises(InputError, match="no Dask answer within 1 s"):
        scheduler_client(silent_address, connect_timeout_s=TIMEOUT_S)
    assert TIMEOUT_S <= time.monotonic() - start < TIMEOUT_S + STARTUP_ALLOWANCE_S


def test_an_address_dask_cannot_parse_is_refused_at_once():
    with pytest.raises(InputError, match="unknown address scheme 'nonsense'"):
        scheduler_client("nonsense://x", connect_timeout_s=TIMEOUT_S)


def test_a_running_scheduler_is_connected():
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        client = scheduler_client(cluster.scheduler_address, connect_timeout_s=10.0)
        try:
            assert client.submit(sum, [1, 2]).result() == 3
        finally:
            client.close()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    pytest.importorskip("skimage")
    from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

    model = example_omni_model(96)
    sequence = synthetic_sequence(model, 3, seed=2, max_step_rad=0.03, band_px=example_band_px(model))
    return write_synthetic_dataset(tmp_path_factory.mktemp("connect") / "set", sequence)


@pytest.mark.slow
@pytest.mark.parametrize("address_fixture", ["http_address", "silent_address"])
def test_sweep_prints_one_line_and_no_progress_bar(request, dataset, tmp_path, capsys, address_fixture):
    """The progress bar is shown (no --no-progress) and yet nothing but the error line is printed."""
    address = request.getfixturevalue(address_fixture)
    code = main(["sweep", str(dataset), "--tile-size", "32", "--overlap", "0", "--scheduler", address,
                 "--connect-timeout", "1", "--out", str(tmp_path / "out")])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "\r" not in captured.err
    assert captured.err.startswith(f"ifmi sweep: error: --scheduler: cannot connect to a Dask scheduler at "
                                   f"{address!r}: no Dask answer within 1 s")
    assert not (tmp_path / "out" / "cells").exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_connect_timeout_must_be_positive_seconds(dataset, tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exit_info:
        main(["sweep", str(dataset), "--tile-size", "32", "--overlap", "0", "--connect-timeout", value,
              "--out", str(tmp_path / "out")])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == (f"ifmi sweep: error: argument --connect-timeout: expected seconds > 0, "
                                       f"got {value!r}\n")
