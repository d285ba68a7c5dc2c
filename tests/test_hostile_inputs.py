"""Big and odd inputs, the Dask cluster, and the machine's own failures (issue 29).

* the local Dask cluster listens on 127.0.0.1 only, speaks TLS with a certificate of its own
  run, and serves no web page unless asked: another user cannot submit work to it;
* a FIFO or a device given as a mesh, texture, material file, scan, table or spec is refused
  (named), never read (which would block for ever);
* a mesh too dense for the quadratic pair search is refused before the search, naming the
  number of faces that would fit;
* a full disk, a file-size limit or a busy port is named (exit 2), not an "internal error";
* smaller holes: Makefile paths with spaces, a sweep that built nothing, stray ``vt`` rows,
  unknown keys inside keyframes.
"""

from __future__ import annotations

import errno
import os
import re
import resource
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pysolver.cli import main
from pysolver.errors import EXIT_BAD_INPUT, InputError

REPO = Path(__file__).resolve().parent.parent
SHAPE = "regular:rows=2,cols=2"


def _cli(argv, capsys) -> tuple[int, str]:
    rc = main(["--quiet", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.err + cap.out


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO))


# ---------------------------------------------------------------- the Dask cluster


def _listening_ports(pids) -> set:
    """(ip, port) of the TCP sockets in LISTEN state owned by ``pids``."""
    inodes = set()
    for pid in pids:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            try:
                link = os.readlink(fd)
            except OSError:
                continue
            if link.startswith("socket:["):
                inodes.add(link[8:-1])
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:          # 0A = LISTEN
                ip, port = f[1].split(":")
                out.add((ip, int(port, 16)))
    return out


def _family(pid: int) -> list[int]:
    """``pid`` and all its descendants (the workers and their nannies)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for t in Path(f"/proc/{p}/task").iterdir():
            with_children = t / "children"
            if with_children.exists():
                todo += [int(c) for c in with_children.read_text().split()]
    return out


def test_the_local_cluster_is_loopback_tls_and_only_ours():
    distributed = pytest.importorskip("distributed")
    from pysolver.distributed import dask_client

    with dask_client(workers=1, progress=False) as client:
        addr = client.scheduler.address
        assert addr.startswith("tls://127.0.0.1:"), addr
        assert client.submit(sum, [1, 2]).result() == 3
        ports = _listening_ports(_family(os.getpid()))
        assert ports, "no listening socket found"
        # every socket on 127.0.0.1 (0100007F in /proc's byte order)
        assert {ip for ip, _ in ports} == {"0100007F"}, ports
        # another user, without this run's certificate, cannot submit anything
        for intruder in (addr.replace("tls://", "tcp://"), addr):
            with pytest.raises((OSError, TimeoutError)):
                c = distributed.Client(intruder, timeout="3s",
                                       security=distributed.security.Security.temporary()
                                       if intruder == addr else None)
                c.close()
        # no web page: no dashboard, no JSON identity of the scheduler
        for _ip, port in ports:
            with socket.create_connection(("127.0.0.1", port), timeout=3) as s:
                s.sendall(b"GET /json/identity.json HTTP/1.0\r\n\r\n")
                s.settimeout(3)
                try:
                    answer = s.recv(200)
                except (TimeoutError, OSError):
                    answer = b""
            assert b"200 OK" not in answer, (port, answer)


def test_a_plain_tcp_scheduler_is_warned_about(monkeypatch):
    import distributed

    from pysolver.distributed import PlainSchedulerWarning, dask_client

    # nothing listens: the client gives up after its timeout (20 s), 1 s here
    real = distributed.Client
    monkeypatch.setattr(distributed, "Client",
                        lambda address, timeout: real(address, timeout="1s"))
    with socket.socket() as s:                           # a closed port: nothing listens
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.warns(PlainSchedulerWarning, match="plain tcp: anyone who can reach it"):
        with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
            with dask_client(f"tcp://127.0.0.1:{port}", progress=False):
                pass


# ---------------------------------------------------------------- FIFOs and devices


@pytest.fixture
def fifo_room(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "pipe.obj")
    return tmp_path


def test_a_fifo_as_the_mesh_is_refused_not_read(fifo_room):
    r = subprocess.run([sys.executable, "-m", "pysolver.cli", "design", "pipe.obj"],
                       cwd=fifo_room, capture_output=True, text=True, timeout=120, env=_env())
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    assert "pipe.obj is a FIFO (named pipe), not a file" in r.stderr


def test_material_and_texture_files_named_by_a_mesh_are_never_opened(fifo_room, capsys):
    """An OBJ's mtllib and a PLY's texture are not read at all (one could be a FIFO)."""
    os.mkfifo(fifo_room / "mat.mtl")
    os.mkfifo(fifo_room / "tex.png")
    (fifo_room / "m.obj").write_text("mtllib mat.mtl\nusemtl a\nv 0 0 0\nv 30 0 0\n"
                                     "v 0 30 0\nf 1 2 3\n")
    (fifo_room / "m.ply").write_text(
        "ply\nformat ascii 1.0\ncomment TextureFile tex.png\nelement vertex 3\n"
        "property float x\nproperty float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n0 0 0\n30 0 0\n0 30 0\n3 0 1 2\n")
    code = ("import sys; from pathlib import Path; from pysolver.design.mesh_input import "
            "_read_trimesh; print(len(_read_trimesh(Path(sys.argv[1])).faces))")
    for f in ("m.obj", "m.ply"):
        r = subprocess.run([sys.executable, "-c", code, f], cwd=fifo_room, capture_output=True,
                           text=True, timeout=120, env=_env())
        assert r.returncode == 0 and r.stdout.strip() == "1", r.stderr


@pytest.mark.parametrize("case", ["scan", "time-file", "material", "table", "spec",
                                  "device"])
def test_other_inputs_that_are_fifos_or_devices_are_refused(fifo_room, capsys, case):
    pipe = fifo_room / "pipe"
    os.mkfifo(pipe)
    if case in ("scan", "table"):
        assert main(["--quiet", "design", SHAPE, "--out", "d"]) == 0
    if case == "scan":
        argv, pat = ["compare-scan", "d", "pipe"], r"scan file .*pipe is a FIFO"
    elif case == "time-file":
        argv, pat = ["design", SHAPE, "--time-file", "pipe"], r"time-file .*pipe: not a regular"
    elif case == "material":
        argv, pat = ["build", SHAPE, "--material", "pipe", "--no-render", "--no-sim"], \
            r"not a regular file"
    elif case == "table":
        (fifo_room / "d" / "cells.csv").unlink()
        os.mkfifo(fifo_room / "d" / "cells.csv")
        argv, pat = ["render", "d", "--renderer", "fast"], r"cells table .*cells\.csv is a FIFO"
    elif case == "spec":
        argv, pat = ["sweep", "pipe"], r"sweep spec pipe is a FIFO"
    else:
        argv, pat = ["build", "/dev/zero"], r"/dev/zero is a character device, not a file"
    rc, msg = _cli(argv, capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert "Traceback" not in msg
    assert re.search(pat, msg), msg


# ---------------------------------------------------------------- memory


def test_a_mesh_too_dense_for_the_pair_search_is_refused_first(monkeypatch):
    import trimesh

    from pysolver.design import sequencing

    m = trimesh.creation.icosphere(subdivisions=4, radius=40.0)       # 5120 faces
    budget = 2e6                                                       # bytes, as if free
    monkeypatch.setattr(sequencing, "available_memory", lambda: budget / 0.5)
    with pytest.raises(InputError, match=r"has 5120 faces, too dense") as e:
        sequencing.sequencing_landscape(m.vertices, m.faces)
    fit = int(e.value.fix.split("at most ")[1].split()[0])
    assert 0 < fit < 5120
    # a mesh of that many faces fits
    small = trimesh.creation.icosphere(subdivisions=2, radius=40.0)   # 320 faces
    assert len(small.faces) <= fit
    from scipy.spatial import cKDTree

    pairs = sequencing.check_pair_memory(cKDTree(small.vertices), len(small.faces), 12.0)
    true = len(cKDTree(small.vertices).query_pairs(12.0))
    assert abs(pairs - true) <= 0.1 * true + 10                        # the estimate holds


# ---------------------------------------------------------------- the machine's failures


def test_a_file_size_limit_is_named_and_leaves_nothing(tmp_path):
    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))

    r = subprocess.run([sys.executable, "-m", "pysolver.cli", "--quiet", "design", SHAPE,
                        "--out", "X"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=120, env=_env(), preexec_fn=limit)
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    assert "the file is too large for its file system" in r.stderr, r.stderr
    assert "internal error" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_is_named(tmp_path, monkeypatch, capsys):
    from pysolver.core import manifest, writes

    monkeypatch.chdir(tmp_path)
    real = manifest.write_new
    calls = []

    def full(path, data):
        calls.append(path)
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, data)

    for mod in (manifest, writes):     # the stamp's writer and the files' writer
        monkeypatch.setattr(mod, "write_new", full)
    rc, msg = _cli(["design", SHAPE, "--out", "X"], capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert "no space left on the device (the disk is full)" in msg
    assert "internal error" not in msg
    for mod in (manifest, writes):
        monkeypatch.setattr(mod, "write_new", real)
    rc, msg = _cli(["design", SHAPE, "--out", "X"], capsys)      # and a rebuild works
    assert rc == 0, msg


def test_a_busy_port_is_named(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["--quiet", "design", SHAPE, "--out", "d"]) == 0
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rc, msg = _cli(["studio", "d", "--port", port, "--no-browser"], capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert f"port {port} on 127.0.0.1 is in use" in msg and "another --port" in msg


# ---------------------------------------------------------------- smaller holes


def test_makefile_shape_path_with_spaces_and_dots(tmp_path):
    (tmp_path / "my shells").mkdir()
    (tmp_path / "my shells" / "petal v2.obj").write_text("v 0 0 0\n")
    fake = tmp_path / "py"
    fake.write_text("#!/bin/sh\nfor a in \"$@\"; do echo \"[$a]\"; done\n")
    fake.chmod(0o755)
    for shape, name in (("my shells/petal v2.obj", "petal v2"), ("dome:size=1.5",
                                                                  "dome:size=1.5")):
        r = subprocess.run(["make", "-s", "-f", str(REPO / "Makefile"), "-o", ".venv/.installed",
                            f"PY={fake}", "report", f"shape={shape}"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        assert f"[build/{name}]" in r.stdout.splitlines(), r.stdout


def test_a_sweep_that_built_nothing_fails(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "s.toml"
    spec.write_text('name = "none"\n[base]\nshape = "regular"\nvertices = 50\n')
    rc, msg = _cli(["sweep", spec, "--workers", "1"], capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert "1 of 1 variant(s) were not built" in msg and "--vertices 50 has no effect" in msg


def test_stray_vt_rows_say_to_delete_them(tmp_path):
    """Read as a stencil (--stencil), stray vt rows are refused, saying to delete them for a
    plain mesh; read as a target (the default) they are a texture layout and ignored."""
    from pysolver.design.mesh_input import load_input

    p = tmp_path / "mesh.obj"
    p.write_text("v 0 0 0\nv 30 0 0\nv 0 30 0\nv 30 30 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                 "f 1 2 3\nf 2 4 3\n")
    with pytest.raises(InputError, match=r"3 vt for 4 v") as e:
        load_input(p, stencil=True)
    assert "delete its vt lines" in e.value.fix
    m = load_input(p, validate=False)
    assert m.kind == "mesh" and m.UV is None and len(m.F) == 2


def test_unknown_keys_inside_keyframes_and_edits_are_refused():
    from pysolver.studio.landscape import parse_keyframes, parse_landscape

    assert parse_keyframes({"keyframes": [{"vertex": 1, "time": 30}]}, 4) == [(1, 30.0)]
    with pytest.raises(InputError, match=r"keyframe 0: unknown key\(s\) \['colour'\]"):
        parse_keyframes({"keyframes": [{"vertex": 1, "time": 30, "colour": 1}]}, 4)
    with pytest.raises(InputError, match=r"unknown key\(s\) \['__proto__'\]"):
        parse_landscape({"landscape": [30.0] * 4, "__proto__": {}}, 4)


@pytest.mark.parametrize("bad", [["1.0", 2.0], [True, 2.0], [[1.0], 2.0], "1,2", [1.0]])
def test_a_records_per_cell_list_is_read_never_trusted(bad):
    """A per-cell list in a record (temporal.json, sim/refine.json) is taken only when it is
    a list of n numbers or nulls: a string, a bool, a nested list or a wrong length is no
    sd (None), never a number (np.array would turn "1.0" into 1.0, True into 1.0)."""
    from pysolver.tables import record_numbers
    assert record_numbers(bad, 2) is None
    got = record_numbers([0.5, None], 2)
    assert got[0] == 0.5 and np.isnan(got[1])


def test_predicted_timing_sd_skips_a_bad_record(tmp_path):
    """A refine record with a bad sd list falls back to the program stage's."""
    import json

    from pysolver.tables import PREDICTED_SD, predicted_timing_sd
    (tmp_path / "sim").mkdir()
    (tmp_path / "temporal.json").write_text(json.dumps({PREDICTED_SD: [1.5, None]}))
    (tmp_path / "sim" / "refine.json").write_text(json.dumps({PREDICTED_SD: ["x", 2.0]}))
    sd = predicted_timing_sd(tmp_path, 2)
    assert sd[0] == 1.5 and np.isnan(sd[1])
    (tmp_path / "temporal.json").write_text(json.dumps({PREDICTED_SD: [False, 1.0]}))
    assert predicted_timing_sd(tmp_path, 2) is None


@pytest.mark.parametrize("text", ["not json", "[1, 2]", "\xff"])
def test_a_damaged_program_record_is_named_for_the_refinement(tmp_path, text):
    """refine reads temporal.json (membrane factors, robust): a damaged one is bad input
    (InputError, exit 2) naming the file and the fix, not an internal error."""
    from pysolver.refine import program_record
    assert program_record(tmp_path) == {}
    (tmp_path / "temporal.json").write_text(text, encoding="latin-1")
    with pytest.raises(InputError, match="temporal.json.*damaged") as e:
        program_record(tmp_path)
    assert "program" in e.value.fix
