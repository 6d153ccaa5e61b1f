"""``jaxvo data``: the catalogue, and downloads from a local HTTP server on 127.0.0.1 serving
small archives the tests make: resumed after an interrupted transfer, checked, unpacked
safely into a folder ``jaxvo run`` reads."""

from __future__ import annotations

import hashlib
import io
import tarfile
import threading
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.host.readers.datasets import catalogue, find, unpack
from jaxvo.host.readers.io import open_sequence, preset_from_name
from jaxvo.synth.scenes import make_sequence, write_sequence


class Server:
    """Serves ``files`` (name -> bytes) with HTTP ranges; ``cut`` makes the first request
    of a file stop after that many bytes (the connection closes); ``ranges=False`` answers
    every request with the whole file. ``requests`` records (path, Range header)."""

    def __init__(self, files: dict[str, bytes], *, cut: int | None = None, ranges: bool = True):
        self.files, self.cut, self.ranges = files, cut, ranges
        self.requests: list[tuple[str, str | None]] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):
                name = self.path.lstrip("/")
                rng = self.headers.get("Range")
                server.requests.append((name, rng))
                if name not in server.files:
                    self.send_error(404)
                    return
                blob = server.files[name]
                start = int(rng[6:-1]) if rng and server.ranges else 0
                if start >= len(blob) and rng:
                    self.send_response(416)
                    self.send_header("Content-Range", f"bytes */{len(blob)}")
                    self.end_headers()
                    return
                self.send_response(206 if start else 200)
                if start:
                    self.send_header("Content-Range", f"bytes {start}-{len(blob) - 1}/{len(blob)}")
                self.send_header("Content-Length", str(len(blob) - start))
                self.end_headers()
                body = blob[start:]
                if server.cut is not None and len(server.requests) == 1:
                    body = body[: server.cut]  # the connection breaks here
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory) -> Path:
    """A 3-frame sequence in the TUM layout, in a folder named as TUM names fr3/walking_xyz."""
    root = tmp_path_factory.mktemp("src") / "rgbd_dataset_freiburg3_walking_xyz"
    write_sequence(make_sequence("handheld_fast", frames=3, seed=0), root)
    (root / "camera.txt").unlink()  # as TUM's archives: the camera comes from the name
    return root


def tgz_of(folder: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as t:
        t.add(folder, arcname=folder.name)
    return buf.getvalue()


def zip_of(folder: Path, arcname: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for p in sorted(folder.rglob("*")):
            z.write(p, f"{arcname}/{p.relative_to(folder)}")
    return buf.getvalue()


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_catalogue_follows_the_publishers_names():
    tum, bonn = catalogue("tum"), catalogue("bonn")
    assert len(tum) == 47 and len(bonn) == 26
    e = find("tum", "fr3/walking_xyz")
    assert e.url == ("https://cvg.cit.tum.de/rgbd/dataset/freiburg3/"
                     "rgbd_dataset_freiburg3_walking_xyz.tgz")
    assert find("tum", "rgbd_dataset_freiburg3_walking_xyz") == e == find(
        "tum", "freiburg3/walking_xyz")
    assert find("tum", "fr3/walking_xyz", bag=True).url.endswith("freiburg3_walking_xyz.bag")
    assert find("bonn", "balloon").url == ("https://www.ipb.uni-bonn.de/html/projects/"
                                           "rgbd_dynamic2019/rgbd_bonn_balloon.zip")
    # every folder's name gives jaxvo run its camera, as an unpacked download has no camera.txt
    for entry in tum + bonn:
        want = "bonn" if entry.dataset == "bonn" else f"tum_fr{entry.name[2]}"
        assert preset_from_name(entry.folder) == want, entry
    assert len({e.name for e in tum}) == len(tum)


def test_list(capsys):
    code, out, _ = cli(capsys, "data", "list", "bonn")
    assert code == 0 and len(out.splitlines()) == 26 and "rgbd_bonn_crowd3" in out


def test_interrupted_download_resumes_and_unpacks(sequence_dir, tmp_path, capsys):
    blob = tgz_of(sequence_dir)
    name = "rgbd_dataset_freiburg3_walking_xyz.tgz"
    half = len(blob) // 2
    dest = tmp_path / "data"
    argv = ["data", "get", "tum", "fr3/walking_xyz", "--dir", dest, "-q"]
    with Server({name: blob}, cut=half) as srv:
        code, out, err = cli(capsys, *argv, "--mirror", srv.url)
        assert code == 2 and err.count("\n") == 1 and "run the same command again to resume" in err
        assert (dest / (name + ".part")).stat().st_size == half
        code, out, err = cli(capsys, *argv, "--mirror", srv.url)
        assert code == 0, err
    assert srv.requests == [(name, None), (name, f"bytes={half}-")]
    target = dest / "rgbd_dataset_freiburg3_walking_xyz"
    assert f"next: jaxvo run {target} --out fr3_walking_xyz.txt" in out
    assert not (dest / name).exists() and not (dest / (name + ".part")).exists()
    assert sorted(p.name for p in dest.iterdir()) == [target.name]  # no staging left
    seq = open_sequence(target)
    assert len(seq) == 3 and seq.camera_source == "preset tum_fr3, from the folder name"
    for f in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        assert (target / f).read_bytes() == (sequence_dir / f).read_bytes()
    code, out, _ = cli(capsys, *argv)  # there already: nothing downloaded
    assert code == 0 and "is there already" in out


def test_server_without_ranges_restarts(sequence_dir, tmp_path, capsys):
    blob = zip_of(sequence_dir, "rgbd_bonn_balloon")
    name = "rgbd_bonn_balloon.zip"
    (tmp_path / (name + ".part")).write_bytes(b"stale bytes of another try")
    digest = hashlib.sha256(blob).hexdigest()
    with Server({name: blob}, ranges=False) as srv:
        code, _, err = cli(capsys, "data", "get", "bonn", "balloon", "--dir", tmp_path,
                             "--mirror", srv.url, "--sha256", digest, "--keep-archive", "-q")
    assert code == 0, err
    assert (tmp_path / name).read_bytes() == blob  # the stale part was not kept
    assert len(open_sequence(tmp_path / "rgbd_bonn_balloon")) == 3


def test_checksum_mismatch_removes_the_download(sequence_dir, tmp_path, capsys):
    name = "rgbd_bonn_crowd.zip"
    with Server({name: zip_of(sequence_dir, "rgbd_bonn_crowd")}) as srv:
        code, _, err = cli(capsys, "data", "get", "bonn", "crowd", "--dir", tmp_path,
                           "--mirror", srv.url, "--sha256", "0" * 64, "-q")
    assert code == 2 and err.count("\n") == 1 and "SHA-256" in err and "removed" in err
    assert list(tmp_path.iterdir()) == []


def test_bag_is_downloaded_not_unpacked(tmp_path, capsys):
    name = "rgbd_dataset_freiburg1_xyz.bag"
    with Server({name: b"#ROSBAG V2.0\n" + bytes(1000)}) as srv:
        code, out, err = cli(capsys, "data", "get", "tum", "fr1/xyz", "--bag", "--dir",
                             tmp_path, "--mirror", srv.url, "-q")
    assert code == 0, err
    assert (tmp_path / name).stat().st_size == 1013
    assert f"next: jaxvo run {tmp_path / name} --out fr1_xyz.txt" in out


def test_missing_file_on_server_is_one_line(tmp_path, capsys):
    with Server({}) as srv:
        code, _, err = cli(capsys, "data", "get", "tum", "fr1/xyz", "--dir", tmp_path,
                           "--mirror", srv.url, "-q")
    assert code == 2 and err.endswith("answered 404 Not Found\n") and err.count("\n") == 1


def evil_tar(member: tarfile.TarInfo, data: bytes = b"x") -> Path:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as t:
        ok = tarfile.TarInfo("seq/rgb.txt")
        ok.size = 1
        t.addfile(ok, io.BytesIO(b"x"))
        member.size = len(data) if member.isfile() else 0
        t.addfile(member, io.BytesIO(data) if member.isfile() else None)
    return buf.getvalue()


def unsafe_archives():
    link = tarfile.TarInfo("seq/link")
    link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
    hard = tarfile.TarInfo("seq/hard")
    hard.type, hard.linkname = tarfile.LNKTYPE, "../../outside"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("seq/rgb.txt", "x")
        z.writestr("../zip_evil.txt", "x")
    return {
        "dotdot": (evil_tar(tarfile.TarInfo("seq/../../evil.txt")), "outside the folder"),
        "absolute": (evil_tar(tarfile.TarInfo("/tmp/jaxvo_evil.txt")), "outside the folder"),
        "symlink": (evil_tar(link), "link or device"),
        "hardlink": (evil_tar(hard), "link or device"),
        "zip_dotdot": (buf.getvalue(), "outside the folder"),
    }


@pytest.mark.parametrize("case", sorted(unsafe_archives()))
def test_unsafe_archives_unpack_nothing(tmp_path, case):
    blob, expect = unsafe_archives()[case]
    archive = tmp_path / "a.tgz"
    archive.write_bytes(blob)
    dest = tmp_path / "out" / "deep"
    dest.mkdir(parents=True)
    with pytest.raises(InputError, match=expect):
        unpack(archive, dest)
    assert list(dest.iterdir()) == []  # not even the safe member before it, nor staging
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path / "out" / "evil.txt").exists()
    assert not Path("/tmp/jaxvo_evil.txt").exists()


def test_corrupt_archive_is_one_line(tmp_path, sequence_dir, capsys):
    blob = bytearray(tgz_of(sequence_dir))
    blob[len(blob) // 2] ^= 0xFF  # a flipped byte: the gzip CRC fails
    name = "rgbd_dataset_freiburg3_walking_xyz.tgz"
    with Server({name: bytes(blob)}) as srv:
        code, _, err = cli(capsys, "data", "get", "tum", "fr3/walking_xyz", "--dir", tmp_path,
                           "--mirror", srv.url, "-q")
    assert code == 2 and "cannot unpack" in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # kept, to look at


def flat_tgz_of(folder: Path) -> bytes:
    """The sequence's files at the archive's top level, without its folder."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as t:
        for p in sorted(folder.iterdir()):
            t.add(p, arcname=p.name)
    return buf.getvalue()


@pytest.mark.parametrize("make", ["flat", "renamed"])
def test_an_archive_without_the_expected_folder_moves_nothing(sequence_dir, tmp_path, capsys,
                                                               make):
    """rgb/, depth/ and the lists were moved into --dir (default: the current folder) before
    the error; now nothing leaves the staging folder but the complete sequence."""
    blob = flat_tgz_of(sequence_dir) if make == "flat" else zip_of(sequence_dir, "other_name")
    name = "rgbd_dataset_freiburg3_walking_xyz.tgz"
    dest = tmp_path / "data"
    with Server({name: blob}) as srv:
        code, _, err = cli(capsys, "data", "get", "tum", "fr3/walking_xyz", "--dir", dest,
                           "--mirror", srv.url, "-q")
    assert code == 2 and err.count("\n") == 1, err
    assert "holds no rgbd_dataset_freiburg3_walking_xyz/rgb.txt (its top level: " in err
    assert ("depth, depth.txt" if make == "flat" else "other_name") in err
    assert sorted(p.name for p in dest.iterdir()) == [name]  # the archive, to look at


def test_only_the_sequence_folder_is_moved_out_of_the_archive(sequence_dir, tmp_path):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as t:
        t.add(sequence_dir, arcname=sequence_dir.name)
        t.add(sequence_dir / "rgb.txt", arcname="stray.txt")
    archive = tmp_path / "a.tgz"
    archive.write_bytes(buf.getvalue())
    dest = tmp_path / "out"
    dest.mkdir()
    tops = unpack(archive, dest, require=f"{sequence_dir.name}/rgb.txt")
    assert tops == [dest / sequence_dir.name]
    assert sorted(p.name for p in dest.iterdir()) == [sequence_dir.name]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_names_the_file_not_the_network(sequence_dir, tmp_path, capsys,
                                                     monkeypatch):
    """It advised to resume ('run the same command again') or to download again, neither of
    which helps on a full disk."""
    name = "rgbd_dataset_freiburg3_walking_xyz.tgz"
    part = tmp_path / (name + ".part")
    part.symlink_to("/dev/full")  # the download's bytes land on a full disk
    with Server({name: tgz_of(sequence_dir)}) as srv:
        code, _, err = cli(capsys, "data", "get", "tum", "fr3/walking_xyz", "--dir", tmp_path,
                           "--mirror", srv.url, "-q")
    assert code == 2 and err == f"jaxvo: error: {part}: No space left on device\n", err
    # unpacking onto a full disk: the file that could not be written, not the archive's fault
    from jaxvo.host.readers import datasets

    real_copy = datasets._copy

    def onto_full_disk(src, target):
        target.symlink_to("/dev/full")
        real_copy(src, target)

    monkeypatch.setattr(datasets, "_copy", onto_full_disk)
    archive = tmp_path / "a.tgz"
    archive.write_bytes(tgz_of(sequence_dir))
    (tmp_path / "out").mkdir()
    with pytest.raises(OSError, match="No space left on device") as got:
        unpack(archive, tmp_path / "out")
    assert "download it" not in str(got.value) and ".a.tgz.unpacking" in got.value.filename
    assert list((tmp_path / "out").iterdir()) == []  # nothing unpacked, no staging left
