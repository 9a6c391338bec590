"""The ADCS kernels in C (firmware/adcs/native/adcsk.c, ``make natmod``): under micropython they give the Python
forms' results bit for bit, kernel by kernel on seeded inputs and over every cycle of a recorded session with
SatB's GNSS; bad arguments raise; the build script refuses a tarball that is not the pinned one."""

import io
import json
import os
import shutil
import subprocess
import tarfile

import pytest

from tools import natmod_build
from tests.adcs_lean_common import record_session
from tests.test_firmware_mp import MICROPYTHON, ROOT

MODULE = natmod_build.TARGET


def need_module():
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed in the venv")
    if not os.path.exists(MODULE):
        pytest.skip("firmware/adcs/adcsk.mpy is not built (make natmod says why)")


def digests(path, *args):
    env = dict(os.environ, MICROPYPATH=path + ":.frozen")
    p = subprocess.run([MICROPYTHON, "-X", "heapsize=64M", os.path.join(ROOT, "tests", "mp", "adcsk_digests.py")]
                       + [str(a) for a in args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def without_module(tmp_path):
    """The firmware and protocol trees without the C kernels (the Python forms run)."""
    root = tmp_path / "py"
    for d in ("firmware", "protocol"):
        shutil.copytree(os.path.join(ROOT, d), root / d, ignore=shutil.ignore_patterns("*.mpy", "__pycache__"))
    return str(root)


def test_the_c_kernels_equal_the_python_forms_bit_for_bit(tmp_path):
    need_module()
    cfg, rec = record_session(tmp_path)
    c = digests(ROOT, cfg, rec)
    py = digests(without_module(tmp_path), cfg, rec)
    assert c.pop("kernels") is True and py.pop("kernels") is False
    assert c["session cycles"] == 60 and c["satb fused"] > 40     # the smoother's update ran
    assert len(c) > 25
    for key in sorted(py):
        assert c[key] == py[key], key


def test_the_c_kernels_refuse_bad_buffers():
    need_module()
    script = "\n".join([
        "from array import array",
        "from firmware.adcs import adcsk",
        "def err(f, *a):",
        "    try:",
        "        f(*a)",
        "    except (TypeError, ValueError) as e:",
        "        return type(e).__name__",
        "    return 'none'",
        "f = array('f', bytes(4 * 36))",
        "print(err(adcsk.matmul, f, array('i', bytes(4 * 36)), f, 6, 6, 6),",
        "      err(adcsk.matmul, f, array('f', bytes(4 * 35)), f, 6, 6, 6),",
        "      err(adcsk.joseph_select, f, 6, 4, 3, f, f, f, f, f),",
        "      err(adcsk.rows_mul_mirror, array('d', bytes(8 * 36)), 6, 0, 0, 7, [0.0] * 36),",
        "      err(adcsk.cholesky, f, f, 6))",
    ])
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
    p = subprocess.run([MICROPYTHON, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["TypeError", "ValueError", "ValueError", "ValueError", "none"]


def _tarball(path, top):
    with tarfile.open(path, "w:xz") as tf:
        for name, data in (("py/dynruntime.mk", b"# mk\n"), ("tools/mpy_ld.py", b"# ld\n"), ("ports/x.c", b"x")):
            info = tarfile.TarInfo("%s/%s" % (top, name))
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))


def test_the_source_is_taken_only_when_its_sha256_is_the_pinned_one(tmp_path):
    import hashlib
    tar = tmp_path / "src.tar.xz"
    _tarball(tar, "micropython-%s" % natmod_build.MP_VERSION)
    url = tar.as_uri()
    with pytest.raises(natmod_build.BuildError, match="SHA-256"):
        natmod_build.fetch_source(str(tmp_path / "a"), url, "0" * 64)
    assert not (tmp_path / "a").exists()                     # nothing partial left
    good = hashlib.sha256(tar.read_bytes()).hexdigest()
    dest = natmod_build.fetch_source(str(tmp_path / "b"), url, good)
    assert sorted(os.listdir(dest)) == ["py", "tools"]       # only what the build reads
    with pytest.raises(natmod_build.BuildError, match="cannot download"):
        natmod_build.fetch_source(str(tmp_path / "c"), (tmp_path / "missing.tar.xz").as_uri(), good)


def test_an_optional_build_that_cannot_be_done_says_why_and_succeeds(monkeypatch, capsys):
    def no(arch="x64", src=None):
        raise natmod_build.BuildError("gcc is not installed")
    monkeypatch.setattr(natmod_build, "build", no)
    assert natmod_build.main(["--optional"]) == 0
    err = capsys.readouterr().err
    assert "not built: gcc is not installed" in err and "Python kernels" in err
    assert natmod_build.main([]) == 1


def test_a_module_built_for_another_arch_leaves_the_python_forms(tmp_path):
    """An adcsk.mpy of another arch (or MicroPython version) is refused by the import: the firmware runs its
    Python forms (the safe state), it does not fail."""
    need_module()
    root = without_module(tmp_path)
    data = bytearray(open(MODULE, "rb").read())
    assert data[0] == ord("M") and data[1] == 6              # .mpy version 6; byte 2: sub-version and arch
    data[2] = (data[2] & 0x03) | (5 << 2)                    # arch 5: armv7m
    with open(os.path.join(root, "firmware", "adcs", "adcsk.mpy"), "wb") as fh:
        fh.write(data)
    env = dict(os.environ, MICROPYPATH=root + ":.frozen")
    p = subprocess.run([MICROPYTHON, "-c", "from firmware.adcs import linalg, stkf_lean\nprint(linalg.kernels)"],
                       cwd=root, env=env, capture_output=True, text=True, timeout=60)   # (-c: cwd is on the path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "None"
    p = subprocess.run([MICROPYTHON, "-c", "from firmware.adcs import linalg\nprint(linalg.kernels is None)"],
                       cwd=ROOT, env=dict(os.environ, MICROPYPATH=ROOT + ":.frozen"), capture_output=True,
                       text=True, timeout=60)
    assert p.stdout.strip() == "False"                       # the real one loads


def test_the_archive_comes_from_apts_sources(tmp_path):
    """No archive host in the code: the URIs are apt's own, one-line and deb822 forms, in order, once each;
    deb-src lines, disabled stanzas and files of other names are not read."""
    (tmp_path / "sources.list").write_text(
        "# a comment\ndeb [arch=amd64 signed-by=/k.gpg] http://mirror.example/debian bookworm main\n"
        "deb-src http://src.example/debian bookworm main\ndeb http://mirror.example/debian bookworm-updates main\n")
    d = tmp_path / "sources.list.d"
    d.mkdir()
    (d / "a.sources").write_text("Types: deb\nURIs: http://two.example/debian/\nSuites: trixie\n\n"
                                 "Types: deb\nEnabled: no\nURIs: http://off.example/debian\nSuites: sid\n")
    (d / "b.list.disabled").write_text("deb http://ignored.example/debian sid main\n")
    uris = natmod_build.apt_archive_uris((str(tmp_path / "sources.list"), str(d)))
    assert uris == ["http://mirror.example/debian", "http://two.example/debian"]
    urls = natmod_build.source_urls(uris)
    assert urls[0] == "http://mirror.example/debian/" + natmod_build.POOL_PATH
    assert natmod_build.MP_VERSION in natmod_build.POOL_PATH
    with open(natmod_build.__file__) as f:
        assert "://" not in f.read()                         # no address written into the build
