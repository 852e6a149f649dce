"""``edofproj weights fetch`` against a local HTTP server on the loopback address (stand-in files).

Nothing is downloaded from the internet: the published entries are replaced by small stand-in
files whose SHA-256 is computed here; the server serves them, a corrupted copy, or a truncated
response.
"""

from __future__ import annotations

import hashlib
import http.server
import threading
from pathlib import Path

import pytest

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.perceptual import weights
from edofproj.perceptual.weights import (
    BACKBONE_DOWNLOADS,
    TORCHVISION_WEIGHT_FILES,
    PerceptualWeightsMissing,
    WeightDownload,
    backbone_weights_path,
    fetch_backbone_weights,
)

STAND_IN = {"vgg16": b"vgg16 stand-in " * 1000, "alexnet": b"alexnet stand-in " * 700}


class Handler(http.server.BaseHTTPRequestHandler):
    """Serves ``files`` under ``/models/``; ``truncate`` names are announced in full but cut in half."""

    files: dict[str, bytes] = {}
    truncate: set[str] = set()
    requests: list[str] = []

    def do_GET(self):  # noqa: N802 - http.server's naming
        name = self.path.rsplit("/", 1)[-1]
        type(self).requests.append(name)
        if self.path != f"/models/{name}" or name not in self.files:
            self.send_error(404)
            return
        body = self.files[name]
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body[: len(body) // 2] if name in self.truncate else body)
        if name in self.truncate:
            self.wfile.flush()
            self.close_connection = True

    def log_message(self, *args):
        pass


@pytest.fixture
def server(monkeypatch):
    """A loopback server and stand-in entries for both backbones; yields (base_url, handler)."""
    handler = type("H", (Handler,), {"files": {}, "truncate": set(), "requests": []})
    for backbone, body in STAND_IN.items():
        name = TORCHVISION_WEIGHT_FILES[backbone]
        handler.files[name] = body
        entry = WeightDownload(backbone, name, hashlib.sha256(body).hexdigest())
        monkeypatch.setitem(weights.BACKBONE_DOWNLOADS, backbone, entry)
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/models", handler
    httpd.shutdown()
    httpd.server_close()


def test_published_checksums_match_the_file_names():
    """torchvision's file names end with the first 8 hex digits of the file's SHA-256."""
    for backbone, item in BACKBONE_DOWNLOADS.items():
        assert item.filename == TORCHVISION_WEIGHT_FILES[backbone]
        assert len(item.sha256) == 64 and int(item.sha256, 16) >= 0
        assert item.filename.rsplit("-", 1)[-1] == f"{item.sha256[:8]}.pth"


def test_fetch_downloads_verified_files_where_the_metrics_look(server, tmp_path, capsys):
    base_url, handler = server
    assert main(["weights", "fetch", "--dir", str(tmp_path), "--base-url", base_url]) == 0
    for backbone, body in STAND_IN.items():
        path = tmp_path / TORCHVISION_WEIGHT_FILES[backbone]
        assert path.read_bytes() == body
        assert backbone_weights_path(backbone, tmp_path) == path
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(TORCHVISION_WEIGHT_FILES.values())
    out = capsys.readouterr().out
    assert str(tmp_path / TORCHVISION_WEIGHT_FILES["vgg16"]) in out and "downloaded" in out
    # a second run finds both files and requests nothing
    handler.requests.clear()
    results = fetch_backbone_weights(["vgg16", "alexnet"], tmp_path, base_url)
    assert [r.status for r in results] == ["present", "present"] and handler.requests == []


def test_checksum_mismatch_is_refused_and_nothing_is_left(server, tmp_path, capsys):
    base_url, handler = server
    name = TORCHVISION_WEIGHT_FILES["vgg16"]
    handler.files[name] = STAND_IN["vgg16"][:-1] + b"X"  # one byte differs
    assert main(["weights", "fetch", "--backbone", "vgg16", "--dir", str(tmp_path), "--base-url", base_url]) == 2
    err = capsys.readouterr().err.strip()
    assert "SHA-256" in err and "not the published" in err and len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_mismatch_keeps_an_existing_file_untouched(server, tmp_path):
    base_url, handler = server
    name = TORCHVISION_WEIGHT_FILES["alexnet"]
    (tmp_path / name).write_bytes(b"an older file")
    handler.files[name] = b"corrupted"
    with pytest.raises(EdofprojError, match="not the published"):
        fetch_backbone_weights(["alexnet"], tmp_path, base_url)
    assert (tmp_path / name).read_bytes() == b"an older file"
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_interrupted_download_leaves_no_partial_file(server, tmp_path):
    base_url, handler = server
    handler.truncate.add(TORCHVISION_WEIGHT_FILES["vgg16"])
    with pytest.raises(EdofprojError, match="nothing was kept"):
        fetch_backbone_weights(["vgg16"], tmp_path, base_url)
    assert list(tmp_path.iterdir()) == []


def test_unreachable_server_and_unknown_backbone_are_one_line(server, tmp_path, capsys):
    base_url, _ = server
    assert main(["weights", "fetch", "--dir", str(tmp_path), "--base-url", base_url + "/missing-folder"]) == 2
    assert "cannot download" in capsys.readouterr().err
    assert main(["weights", "fetch", "--backbone", "resnet", "--dir", str(tmp_path)]) == 2
    assert "allowed: vgg16, alexnet" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_missing_backbone_error_names_the_fetch_command(tmp_path, monkeypatch):
    monkeypatch.setattr(weights, "hub_checkpoint_dir", lambda: tmp_path / "hub")
    with pytest.raises(PerceptualWeightsMissing, match="edofproj weights fetch --backbone vgg16"):
        backbone_weights_path("vgg16", tmp_path)
    assert not Path(tmp_path / "hub").exists()
