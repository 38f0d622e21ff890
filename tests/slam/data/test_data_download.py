"""``lrslam download`` against a local HTTP server on 127.0.0.1 (never the real hosts).

The server (``http.server`` with Range support written here) serves a small TUM archive built from real frames
of the shared excerpt and a tiny 7-Scenes-style nested zip; it can cut a connection after N bytes or ignore
Range headers. Downloads, resume, checksums, a full disk, ScanNet's access text and ``--frames`` windows are
checked, and what is unpacked is read back with ``load_dataset``.
"""

import errno
import hashlib
import http.server
import io
import re
import tarfile
import threading
import zipfile

import numpy as np
import pytest

from slam.cli import main
from slam.data import archive, load_dataset
from slam.data.download import KNOWN_CHECKSUMS, fetch, resolve
from slam.errors import SlamInputError

TUM_PATH = "/freiburg1/rgbd_dataset_freiburg1_rpy.tgz"
CHESS_PATH = "/chess.zip"
N_TUM = 4  # associated pairs in the test archive
N_CHESS = 3


class _Handler(http.server.BaseHTTPRequestHandler):
    timeout = 5  # a stuck client cannot hold the server thread for long

    def do_GET(self):  # noqa: N802 (http.server's name)
        state = self.server.state
        state["requests"].append((self.path, self.headers.get("Range")))
        data = state["files"].get(self.path)
        if data is None:
            self.send_error(404)
            return
        start = 0
        m = re.fullmatch(r"bytes=(\d+)-", self.headers.get("Range") or "")
        if m and not state["ignore_range"]:
            start = int(m.group(1))
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        body = data[start:]
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        cut = state["drop_after"].pop(self.path, None)  # only the first request is cut
        self.wfile.write(body if cut is None else body[:cut])

    def log_message(self, *args):
        pass


def _tum_archive(shared) -> bytes:
    """rgbd_dataset_freiburg1_rpy.tgz as TUM ships it (no associations.txt), with the excerpt's first pairs."""
    src = shared / "tum_fr1_rpy"
    pairs = [ln.split() for ln in (src / "associations.txt").read_text().splitlines()[:N_TUM]]
    lo, hi = float(pairs[0][0]) - 0.5, float(pairs[-1][2]) + 0.5
    gt = [ln for ln in (src / "groundtruth.txt").read_text().splitlines()
          if ln.startswith("#") or lo <= float(ln.split()[0]) <= hi]
    texts = {
        "rgb.txt": "# color images\n# timestamp filename\n" + "".join(f"{p[0]} {p[1]}\n" for p in pairs),
        "depth.txt": "# depth maps\n# timestamp filename\n" + "".join(f"{p[2]} {p[3]}\n" for p in pairs),
        "groundtruth.txt": "\n".join(gt) + "\n",
    }
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:
        for name, text in texts.items():
            info = tarfile.TarInfo(f"rgbd_dataset_freiburg1_rpy/{name}")
            info.size = len(text.encode())
            tar.addfile(info, io.BytesIO(text.encode()))
        for p in pairs:
            for rel in (p[1], p[3]):
                tar.add(src / rel, arcname=f"rgbd_dataset_freiburg1_rpy/{rel}")
    return buf.getvalue()


def _zip(entries: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _chess_archive() -> bytes:
    """chess.zip as Microsoft ships it: chess/seq-01.zip holding seq-01/frame-NNNNNN.{color,depth}.png, .pose.txt."""
    import imageio.v3 as iio

    frames = {}
    for i in range(N_CHESS):
        stem = f"seq-01/frame-{i:06d}"
        frames[f"{stem}.color.png"] = iio.imwrite("<bytes>", np.full((480, 640, 3), 40 * i, np.uint8), extension=".png")
        frames[f"{stem}.depth.png"] = iio.imwrite("<bytes>", np.full((480, 640), 1500, np.uint16), extension=".png")
        pose = np.eye(4)
        pose[0, 3] = 0.01 * i
        frames[f"{stem}.pose.txt"] = "".join("\t".join(f"{v:.7e}" for v in row) + "\t\n" for row in pose)
    return _zip({"chess/seq-01.zip": _zip(frames), "chess/TrainSplit.txt": "sequence1\n"})


@pytest.fixture(scope="module")
def server(shared_data):
    """A local server with the two archives; ``state`` is reset for every test by ``mirror``."""
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.daemon_threads = True
    httpd.archives = {TUM_PATH: _tum_archive(shared_data), CHESS_PATH: _chess_archive()}
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    stopper = threading.Timer(120, httpd.shutdown)  # bounded even if the module's teardown never runs
    stopper.daemon = True
    stopper.start()
    yield httpd
    stopper.cancel()
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture
def mirror(server, monkeypatch):
    """The server's base URL, with fresh state; proxies bypassed and a short client timeout."""
    server.state = {"files": dict(server.archives), "requests": [], "drop_after": {}, "ignore_range": False}
    monkeypatch.setenv("no_proxy", "127.0.0.1,localhost")
    monkeypatch.setenv("NO_PROXY", "127.0.0.1,localhost")
    monkeypatch.setattr(archive, "TIMEOUT_S", 5.0)
    monkeypatch.delenv("LRSLAM_DOWNLOAD_MIRROR", raising=False)
    return f"http://127.0.0.1:{server.server_address[1]}"


def test_download_unpacks_into_the_loader_layout_and_rerun_is_a_no_op(server, mirror, tmp_path, capsys):
    to = tmp_path / "data"
    assert main(["download", "tum", "fr1_rpy", "--to", str(to), "--mirror", mirror]) == 0
    out = capsys.readouterr().out
    seq = to / "rgbd_dataset_freiburg1_rpy"
    assert f"lrslam run --config tum/fr1_rpy --data {seq} --device cuda" in out
    assert f"lrslam run --config tum/fr1_rpy --data {seq}                # real time on the CPU" in out
    ds = load_dataset(seq)
    assert len(ds) == N_TUM and ds.camera == "fr1" and tuple(ds[0].color.shape) == (480, 640, 3)
    assert not list(to.glob("*.tgz*")) and not list(to.glob(".*"))  # archive deleted, no leftovers

    # 7-Scenes through the environment variable: the inner seq-01.zip is unpacked too
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("LRSLAM_DOWNLOAD_MIRROR", mirror)
        assert main(["download", "7scenes", "chess", "--to", str(to)]) == 0
    chess = to / "7scenes" / "chess" / "seq-01"
    assert f"lrslam run --data {chess}                # real time on the CPU" in capsys.readouterr().out
    ds = load_dataset(chess)
    assert len(ds) == N_CHESS and tuple(ds[0].depth.shape) == (480, 640)
    assert not list(chess.parent.glob("*.zip"))

    n = len(server.state["requests"])
    assert main(["download", "tum", "freiburg1_rpy", "--to", str(to), "--mirror", mirror]) == 0
    assert len(server.state["requests"]) == n  # nothing fetched again
    assert f"--data {seq}" in capsys.readouterr().out


def test_resume_after_a_cut_connection(server, mirror, tmp_path):
    served = server.archives[TUM_PATH]
    server.state["drop_after"][TUM_PATH] = 300_000
    with pytest.raises(SlamInputError, match="rerun the same command to resume") as exc:
        fetch("tum", "fr1_rpy", tmp_path, mirror=mirror, log=lambda _: None)
    assert mirror + TUM_PATH in str(exc.value) and "\n" not in str(exc.value)
    part = tmp_path / "rgbd_dataset_freiburg1_rpy.tgz.part"
    assert part.stat().st_size == 300_000

    data = fetch("tum", "rgbd_dataset_freiburg1_rpy", tmp_path, mirror=mirror, keep_archive=True, log=lambda _: None)
    assert server.state["requests"][-1] == (TUM_PATH, "bytes=300000-")
    assert (tmp_path / "rgbd_dataset_freiburg1_rpy.tgz").read_bytes() == served
    assert not part.exists() and len(load_dataset(data)) == N_TUM


def test_a_server_ignoring_range_restarts_cleanly(server, mirror, tmp_path):
    server.state["ignore_range"] = True
    (tmp_path / "chess.zip.part").write_bytes(b"junk from an older attempt")
    fetch("7scenes", "chess", tmp_path, mirror=mirror, keep_archive=True, log=lambda _: None)
    assert server.state["requests"][-1][1] == "bytes=26-"
    assert (tmp_path / "chess.zip").read_bytes() == server.archives[CHESS_PATH]


def test_a_complete_part_file_is_not_fetched_again(server, mirror, tmp_path):
    served = server.archives[CHESS_PATH]
    (tmp_path / "chess.zip.part").write_bytes(served)  # killed between the last byte and the rename
    fetch("7scenes", "chess", tmp_path, mirror=mirror, keep_archive=True, log=lambda _: None)
    assert server.state["requests"] == [(CHESS_PATH, f"bytes={len(served)}-")]  # answered 416, nothing re-sent
    assert (tmp_path / "chess.zip").read_bytes() == served


def test_bad_checksum_is_refused_and_nothing_is_kept(server, mirror, tmp_path, monkeypatch):
    monkeypatch.setitem(KNOWN_CHECKSUMS, "chess.zip", ("md5", "0" * 32))
    with pytest.raises(SlamInputError, match="md5 mismatch") as exc:
        fetch("7scenes", "chess", tmp_path, mirror=mirror, log=lambda _: None)
    assert "\n" not in str(exc.value)
    assert list(tmp_path.iterdir()) == []  # no archive, no .part, no unpacked folder

    good = hashlib.sha256(server.archives[CHESS_PATH]).hexdigest()
    assert main(["download", "7scenes", "chess", "--to", str(tmp_path), "--mirror", mirror, "--sha256", good]) == 0
    assert (tmp_path / "7scenes" / "chess" / "seq-01").is_dir()


def test_full_disk_is_a_clear_error_and_keeps_the_partial_file(server, mirror, tmp_path, monkeypatch, capsys):
    written = []

    def fill_up(fh, data):
        if written:
            raise OSError(errno.ENOSPC, "No space left on device")
        fh.write(data)
        written.append(len(data))

    monkeypatch.setattr(archive, "_write", fill_up)
    assert main(["download", "tum", "fr1_rpy", "--to", str(tmp_path), "--mirror", mirror]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]  # the lines before are tqdm's progress bar
    assert err.startswith("lrslam download: error: disk full while writing") and "bytes kept" in err
    assert (tmp_path / "rgbd_dataset_freiburg1_rpy.tgz.part").stat().st_size == written[0] > 0
    assert not (tmp_path / "rgbd_dataset_freiburg1_rpy").exists()


def test_scannet_prints_how_to_request_access(server, mirror, tmp_path, capsys):
    assert main(["download", "scannet", "--to", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "http://www.scan-net.org/" in out and "Terms of Use" in out
    assert not (tmp_path / "d").exists() and server.state["requests"] == []


def test_frames_writes_a_loadable_window(server, mirror, tmp_path, capsys):
    argv = ["download", "tum", "fr1_rpy", "--to", str(tmp_path), "--mirror", mirror, "--frames", "1:3"]
    assert main(argv) == 0
    window = tmp_path / "rgbd_dataset_freiburg1_rpy_1_2"
    assert f"--data {window}" in capsys.readouterr().out
    ds = load_dataset(window)
    assert len(ds) == 2 and ds.camera == "fr1" and tuple(ds[1].color.shape) == (480, 640, 3)
    full = load_dataset(tmp_path / "rgbd_dataset_freiburg1_rpy")
    assert np.allclose(ds.timestamps, full.timestamps[1:3])
    assert sorted(p.name for p in window.iterdir()) == ["SOURCE.md", "associations.txt", "depth", "depth.txt",
                                                       "groundtruth.txt", "rgb", "rgb.txt"]
    assert main(argv) == 0 and len(server.state["requests"]) == 1  # rerun: no-op
    assert main(argv[:-1] + ["2:9"]) == 2
    assert "has 4 associated rgb/depth pairs" in capsys.readouterr().err


def test_names_and_network_errors_are_one_line(mirror, tmp_path, capsys):
    assert resolve("tum", "fr1_rpy") == resolve("tum", "rgbd_dataset_freiburg1_rpy") == resolve("tum", "freiburg1_rpy")
    assert resolve("tum", "fr3_long_office_household").url() == \
        "https://cvg.cit.tum.de/rgbd/dataset/freiburg3/rgbd_dataset_freiburg3_long_office_household.tgz"
    for argv, msg in ((["kitti"], "unknown dataset 'kitti'; expected one of: replica, tum, 7scenes, scannet"),
                      (["tum", "fr1_rpyy"], "unknown TUM sequence 'fr1_rpyy' (did you mean fr1_rpy?)"),
                      (["7scenes", "kitchen"], "expected one of: chess, fire, heads"),
                      (["replica", "room9"], "unknown Replica scene 'room9'"),
                      (["7scenes", "fire"], f"download of {mirror}/fire.zip failed (HTTP 404")):
        assert main(["download", *argv, "--to", str(tmp_path), "--mirror", mirror]) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1, err


def test_archive_members_outside_the_target_are_refused(tmp_path):
    evil = tmp_path / "evil.zip"
    evil.write_bytes(_zip({"Replica/room0/traj.txt": "", "../escaped.txt": "x"}))
    with pytest.raises(SlamInputError, match="outside"):
        archive.unpack(evil, tmp_path / "out")
    assert not (tmp_path / "escaped.txt").exists()
