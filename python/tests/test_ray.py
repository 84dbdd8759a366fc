"""octolod-ray on a simulated 3-node Ray cluster (ray.cluster_utils.Cluster).

The binaries come from $OCTOLOD_BIN and $OCTOLOD_GEN_BIN (default: the
repository's target/release/); tools/ray-tests.sh sets both. Every Ray file
(sessions, sockets, the cluster address file) stays inside the tests' tmp
directories; the nodes advertise loopback addresses only.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
OCTOLOD = os.environ.get("OCTOLOD_BIN") or str(REPO / "target" / "release" / "octolod")
GEN = os.environ.get("OCTOLOD_GEN_BIN") or str(REPO / "target" / "release" / "octolod-gen")
TRIS = int(os.environ.get("OCTOLOD_RAY_TEST_TRIS", "100000"))
RUN_TIMEOUT = 600
PLAN_ARGS = ["--leaf-tris", "1024"]

pytestmark = pytest.mark.skipif(
    not (os.access(OCTOLOD, os.X_OK) and os.access(GEN, os.X_OK)),
    reason=f"needs the octolod binaries ({OCTOLOD}, {GEN}): cargo build --release, or set OCTOLOD_BIN/OCTOLOD_GEN_BIN",
)


def _short_link(target: Path) -> str:
    """A short path to `target`: Ray puts its AF_UNIX sockets (108 bytes at
    most) under its temp dir, and pytest's tmp paths are long."""
    d = tempfile.mkdtemp(prefix="olr-")
    link = os.path.join(d, "t")
    os.symlink(target, link)
    return link


def _octolod_ray() -> list[str]:
    script = Path(sys.executable).with_name("octolod-ray")
    return [str(script)] if script.exists() else [sys.executable, "-m", "octolod_ray"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    base = tmp_path_factory.mktemp("ray")
    link = _short_link(base)
    mp = pytest.MonkeyPatch()
    # Set before Ray is imported: it reads them then. The children
    # (octolod-ray's driver) inherit them.
    mp.setenv("RAY_AUTH_MODE", "disabled")  # Ray >= 2.5x: no token for a throwaway test cluster
    mp.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # nodes on 127.0.0.1, not the host's address
    mp.setenv("RAY_TMPDIR", link)  # the cluster address file lands here, not in /tmp/ray
    mp.delenv("RAY_ADDRESS", raising=False)
    temp_dir = os.path.join(link, "ray")
    os.makedirs(temp_dir, exist_ok=True)
    from ray.cluster_utils import Cluster

    c = Cluster()
    try:
        c.add_node(num_cpus=1, temp_dir=temp_dir, include_dashboard=False)  # the head
        for _ in range(2):
            c.add_node(num_cpus=1, temp_dir=temp_dir)
        c.wait_for_nodes()
        yield c
    finally:
        c.shutdown()
        mp.undo()
        os.unlink(link)
        os.rmdir(os.path.dirname(link))


@pytest.fixture(scope="module")
def mesh(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("mesh") / "terrain.ply"
    subprocess.run([GEN, "--shape", "terrain", "--tris", str(TRIS), "-o", str(out), "--quiet"], check=True, timeout=RUN_TIMEOUT)
    return out


def run_build(cluster, mesh, store, work, *more, octolod=OCTOLOD, shards=4, report=None):
    cmd = _octolod_ray() + [
        "build", str(mesh), "-o", str(store), "--shards", str(shards),
        "--address", cluster.address, "--work", str(work),
        "--octolod", str(octolod), "--mem", "256M",
    ]  # fmt: skip
    if report is not None:
        cmd += ["--json", str(report)]
    cmd += list(more)
    cmd += ["--", *PLAN_ARGS]  # small leaves: every shard builds levels of its own
    return subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT)


def _ok(p: subprocess.CompletedProcess):
    assert p.returncode == 0, f"exit {p.returncode}\nstdout:\n{p.stdout}\nstderr:\n{p.stderr}"


def _files(store: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(store.iterdir())}


def _without_timings(v):
    """store.json minus wall-clock figures (`seconds` fields): a merge's own
    timings are not the store's content."""
    if isinstance(v, dict):
        return {k: _without_timings(x) for k, x in v.items() if k != "seconds"}
    if isinstance(v, list):
        return [_without_timings(x) for x in v]
    return v


def assert_same_store(a: Path, b: Path):
    fa, fb = _files(a), _files(b)
    assert sorted(fa) == sorted(fb), "the stores hold different files"
    assert "nodes.bin" in fa and "store.json" in fa and any(n.startswith("level-") for n in fa)
    for name in fa:
        if fa[name] == fb[name]:
            continue
        if name == "store.json":
            ja, jb = json.loads(fa[name]), json.loads(fb[name])
            assert _without_timings(ja) == _without_timings(jb), "store.json differs beyond its timings"
            continue
        raise AssertionError(f"{name} differs between {a} and {b}")


def _processes_naming(arg: str) -> list[str]:
    """Command lines of the processes that have `arg` among their arguments."""
    found = []
    for pid in os.listdir("/proc"):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = f.read().split(b"\0")
        except OSError:
            continue
        if os.fsencode(arg) in argv:
            found.append(b" ".join(argv).decode(errors="replace"))
    return found


def _script(path: Path, text: str) -> Path:
    path.write_text(text)
    path.chmod(0o755)
    return path


def test_sharded_build_then_resume_skips_every_shard(cluster, mesh, tmp_path):
    store, work = tmp_path / "store", tmp_path / "work"
    p = run_build(cluster, mesh, store, work, report=tmp_path / "first.json")
    _ok(p)
    r = json.loads((tmp_path / "first.json").read_text())
    assert r["ok"] and not r["plan"]["reused"] and not r["merge"]["skipped"]
    shards = r["shards"]
    assert len(shards) == 4
    assert all(s["status"] == "built" and s["attempts"] == 1 for s in shards), shards
    est = [s["est_triangles"] for s in shards]
    assert est == sorted(est, reverse=True), "shards are not submitted largest first"
    for s in shards:
        assert s["wall_seconds"] > 0 and s["max_rss_bytes"] > 0 and s["host"] and s["node_id"]
    assert r["seconds"]["plan"] > 0 and r["seconds"]["merge"] > 0
    assert "shard" in p.stdout and "built" in p.stdout  # the table

    info = subprocess.run([OCTOLOD, "info", str(store)], capture_output=True, text=True, timeout=RUN_TIMEOUT)
    assert info.returncode == 0, info.stderr
    # The merge links the shards' packs in as parts (the shards live in the
    # work directory, on the store's filesystem): no byte copied.
    parts = [p for p in store.iterdir() if ".part-" in p.name]
    assert parts and all(p.stat().st_nlink >= 2 for p in parts), sorted(p.name for p in store.iterdir())
    before = _files(store)

    # The same command again: the plan is reused, the binary skips every
    # shard ("already built"), the store is left as it is.
    p = run_build(cluster, mesh, store, work, report=tmp_path / "second.json")
    _ok(p)
    r2 = json.loads((tmp_path / "second.json").read_text())
    assert r2["plan"]["reused"] and r2["plan_id"] == r["plan_id"]
    assert [s["status"] for s in r2["shards"]] == ["skipped"] * 4, r2["shards"]
    assert r2["merge"]["skipped"]
    assert _files(store) == before

    # --copy (passed on to merge): one pack per level, copied, the same nodes.
    copied = tmp_path / "copied"
    _ok(run_build(cluster, mesh, copied, work, "--copy"))
    names = sorted(p.name for p in copied.iterdir())
    assert not any(".part-" in n for n in names) and all(p.stat().st_nlink == 1 for p in copied.iterdir()), names
    for level in range(2):
        a, b = (
            subprocess.run([OCTOLOD, "-q", "metro", str(mesh), f"{st}@{level}", "--json", "--samples", "20000"], capture_output=True, text=True, timeout=RUN_TIMEOUT)
            for st in (store, copied)
        )
        assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
        assert json.loads(a.stdout)["combined"] == json.loads(b.stdout)["combined"], level


KILLER = r"""#!/bin/bash
# Stand-in for octolod: the first `build --shard {shard}` starts the real
# build, freezes it (SIGSTOP) as soon as its temporary output appears, then
# SIGKILLs it and the Ray worker running this task (its parent), as a
# crashing node would. Everything else is the real binary.
if [ "$1" = build ] && [[ " $* " == *" --shard {shard} "* ]] && mkdir "{mark}" 2>/dev/null; then
    prev=; for a in "$@"; do [ "$prev" = -o ] && out=$a; prev=$a; done
    parent=${{out%/*}} base=${{out##*/}}
    shopt -s nullglob
    "{real}" "$@" &
    child=$!
    for ((n = 0; n < 200000; n++)); do  # octolod writes OUT as .OUT<tag> first, then renames it
        tmp=("$parent"/."$base"*)
        if [ ${{#tmp[@]}} -gt 0 ]; then kill -STOP "$child"; break; fi
        kill -0 "$child" 2>/dev/null || break
    done
    if kill -0 "$child" 2>/dev/null && [ ! -e "$out" ]; then echo "$child" > "{mark}/cut"; fi
    kill -KILL "$child" 2>/dev/null
    kill -KILL "$PPID"
    sleep 60  # not reached: the worker's death kills this script too (PR_SET_PDEATHSIG)
    exit 137
fi
exec "{real}" "$@"
"""


def test_worker_killed_mid_shard_is_retried_and_gives_the_same_store(cluster, mesh, tmp_path):
    # An uninterrupted run first: the reference store, and how long a shard takes.
    ref_store, ref_work = tmp_path / "ref-store", tmp_path / "ref-work"
    _ok(run_build(cluster, mesh, ref_store, ref_work, report=tmp_path / "ref.json"))
    ref = json.loads((tmp_path / "ref.json").read_text())
    victim = ref["shards"][0]  # the largest

    # The same plan (the store id is the plan id), a fresh work directory.
    work = tmp_path / "work"
    work.mkdir()
    for name in ("plan.json", "plan-key.json"):
        shutil.copy(ref_work / name, work / name)
    mark = tmp_path / "killed"
    killer = _script(tmp_path / "octolod-killer", KILLER.format(shard=victim["index"], mark=mark, real=OCTOLOD))
    store = tmp_path / "store"
    p = run_build(cluster, mesh, store, work, "--retries", "2", octolod=killer, report=tmp_path / "killed.json")
    _ok(p)
    assert mark.is_dir(), "the killer never ran"
    assert (mark / "cut").exists(), f"shard {victim['index']} was not caught mid-build"
    r = json.loads((tmp_path / "killed.json").read_text())
    assert r["plan"]["reused"] and r["plan_id"] == ref["plan_id"]
    s = next(s for s in r["shards"] if s["index"] == victim["index"])
    assert s["attempts"] >= 2, s
    assert "end" not in s["attempt_log"][0], "the first attempt was not cut short"
    assert s["status"] == "built", s
    assert all(x["status"] == "built" for x in r["shards"]), r["shards"]
    assert_same_store(ref_store, store)
    # The killed build left no orphan: no process still runs the real binary
    # on this shard's output.
    assert _processes_naming(s["dir"]) == [], "a killed build is still running"


FAILER = r"""#!/bin/bash
# Stand-in for octolod whose `build --shard 1` always fails.
if [ "$1" = build ] && [[ " $* " == *" --shard 1 "* ]]; then
    echo "error: injected failure of this shard" >&2
    exit 1
fi
exec "{real}" "$@"
"""


def test_failing_shard_exits_non_zero_naming_it_then_resumes(cluster, mesh, tmp_path):
    failer = _script(tmp_path / "octolod-failer", FAILER.format(real=OCTOLOD))
    store, work = tmp_path / "store", tmp_path / "work"
    p = run_build(cluster, mesh, store, work, "--retries", "1", octolod=failer, report=tmp_path / "failed.json")
    assert p.returncode == 1, p.stderr
    assert "shard 1 failed after 2 attempts" in p.stderr, p.stderr
    assert "injected failure" in p.stderr, p.stderr
    assert not store.exists()
    r = json.loads((tmp_path / "failed.json").read_text())
    assert not r["ok"] and "shard 1" in r["error"]
    by = {s["index"]: s for s in r["shards"]}
    assert by[1]["status"] == "failed" and by[1]["attempts"] == 2
    assert all(by[i]["status"] == "built" for i in by if i != 1)

    # The same command with a working binary finishes the job: only shard 1 is built.
    p = run_build(cluster, mesh, store, work, report=tmp_path / "resumed.json")
    _ok(p)
    r = json.loads((tmp_path / "resumed.json").read_text())
    assert r["plan"]["reused"]
    assert {s["index"]: s["status"] for s in r["shards"]} == {i: ("built" if i == 1 else "skipped") for i in by}
    assert subprocess.run([OCTOLOD, "info", str(store)], capture_output=True, timeout=RUN_TIMEOUT).returncode == 0


def test_changed_input_is_planned_again(cluster, mesh, tmp_path):
    inp = tmp_path / "in.ply"
    shutil.copy(mesh, inp)
    store, work = tmp_path / "store", tmp_path / "work"
    _ok(run_build(cluster, inp, store, work, shards=2, report=tmp_path / "a.json"))
    a = json.loads((tmp_path / "a.json").read_text())
    subprocess.run([GEN, "--shape", "terrain", "--tris", str(TRIS // 2), "--seed", "7", "-o", str(inp), "--quiet", "--force"], check=True)
    _ok(run_build(cluster, inp, store, work, "--force", shards=2, report=tmp_path / "b.json"))
    b = json.loads((tmp_path / "b.json").read_text())
    assert not b["plan"]["reused"] and b["plan_id"] != a["plan_id"]
    assert all(s["status"] == "built" for s in b["shards"])
    assert sorted(os.listdir(work / "shards")) == [b["plan_id"]], "the old plan's shards were kept"
    assert subprocess.run([OCTOLOD, "info", str(store)], capture_output=True, timeout=RUN_TIMEOUT).returncode == 0


def test_bad_binary_path_is_an_error(tmp_path, mesh):
    p = subprocess.run(
        _octolod_ray() + ["build", str(mesh), "-o", str(tmp_path / "s"), "--shards", "2", "--octolod", str(tmp_path / "nope")],
        capture_output=True, text=True, timeout=RUN_TIMEOUT,
    )  # fmt: skip
    assert p.returncode == 1 and "nope" in p.stderr and "octolod-ray:" in p.stderr, p.stderr


def test_usage_error_exits_2():
    p = subprocess.run(_octolod_ray() + ["build", "x.ply"], capture_output=True, text=True, timeout=RUN_TIMEOUT)
    assert p.returncode == 2 and "required" in p.stderr

