"""The body of one shard task: run `octolod build --plan --shard` on a worker.

This module uses the standard library only (``ray`` is imported lazily, for
the node id): the driver ships it to the workers *by value*, so a worker node
needs Ray (which it has) and the octolod binary at the same path, but not this
package. Data moves only through the shared filesystem: the task gets paths and
returns a small dict of figures, never mesh data.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import socket
import subprocess
import sys
import time

#: ``prctl(PR_SET_PDEATHSIG)``: Linux only.
_PR_SET_PDEATHSIG = 1


class ShardError(RuntimeError):
    """A shard's build failed on this attempt (Ray retries it)."""


def _die_with_parent(parent_pid: int):
    """A ``preexec_fn``: the child gets SIGKILL when the worker that started it
    dies, so a killed worker leaves no orphaned build racing its retry."""

    def setup():
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(None, use_errno=True)
                libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
            except (OSError, AttributeError):
                pass
        # The worker may have died between fork and prctl.
        if os.getppid() != parent_pid:
            os._exit(137)

    return setup


def _node_id() -> str | None:
    try:
        import ray

        return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - figures only
        return None


def _tail(path: str, lines: int = 6, max_chars: int = 2000) -> str:
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 16384))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    all_lines = text.splitlines()
    if size <= 16384 and all_lines and all_lines[0].startswith("$ "):
        all_lines = all_lines[1:]  # the command line this task wrote
    kept = [ln for ln in all_lines if ln.strip()][-lines:]
    return "\n".join(kept)[-max_chars:]


def _write_json(path: str, obj: dict) -> None:
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
    os.replace(tmp, path)


def build_shard(spec: dict) -> dict:
    """Build shard ``spec["index"]``; return its figures.

    ``spec``: ``binary``, ``input``, ``plan``, ``index``, ``out_dir``,
    ``mem`` (or None), ``attempts_dir`` (one record per attempt, on the shared
    filesystem: a worker killed mid-shard leaves its record without an end).

    Returns a dict with ``status`` ``built``, ``skipped`` (the binary said
    "already built") or ``stale`` (the binary refused the plan: the input
    changed). Any other failure raises :class:`ShardError`, which Ray retries
    (``retry_exceptions=True``); a worker that dies is retried by Ray too.
    """
    index = int(spec["index"])
    host = socket.gethostname()
    node = _node_id()
    worker_pid = os.getpid()
    attempts_dir = spec["attempts_dir"]
    os.makedirs(attempts_dir, exist_ok=True)
    started = time.time()
    stem = f"{time.time_ns():020d}-{host}-{worker_pid}"
    record_path = os.path.join(attempts_dir, stem + ".json")
    log_path = os.path.join(attempts_dir, stem + ".log")
    record = {"index": index, "host": host, "node_id": node, "worker_pid": worker_pid, "start": started, "log": log_path}
    _write_json(record_path, record)
    attempt = sum(1 for n in os.listdir(attempts_dir) if n.endswith(".json"))

    cmd = [
        spec["binary"], "build", spec["input"],
        "--plan", spec["plan"],
        "--shard", str(index),
        "-o", spec["out_dir"],
        "--quiet",
    ]  # fmt: skip
    if spec.get("mem"):
        cmd += ["--mem", spec["mem"]]

    t0 = time.monotonic()
    with open(log_path, "wb") as log:
        log.write(("$ " + " ".join(cmd) + "\n").encode())
        log.flush()
        try:
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                close_fds=True,
                preexec_fn=_die_with_parent(worker_pid),
            )
        except OSError as e:
            record.update(end=time.time(), error=f"cannot run {spec['binary']}: {e}")
            _write_json(record_path, record)
            raise ShardError(f"cannot run {spec['binary']} on {host}: {e}") from None
        # wait4 gives this child's own peak RSS; RUSAGE_CHILDREN would mix in
        # the earlier tasks' children of a reused worker.
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.monotonic() - t0
    rss_kib = usage.ru_maxrss if sys.platform != "darwin" else usage.ru_maxrss // 1024
    rc = proc.returncode

    with open(log_path, "rb") as f:
        f.readline()  # the command line, not the binary's output
        output = f.read().decode("utf-8", "replace")
    result = {
        "index": index,
        "host": host,
        "node_id": node,
        "worker_pid": worker_pid,
        "attempt": attempt,
        "wall_seconds": round(wall, 3),
        "max_rss_bytes": int(rss_kib) * 1024,
        "returncode": rc,
        "log": log_path,
    }
    if rc == 0:
        result["status"] = "skipped" if "already built" in output else "built"
    elif rc == 1 and "stale" in output.lower():
        result["status"] = "stale"
        result["message"] = _tail(log_path, 3)
    else:
        why = f"killed by signal {-rc}" if rc < 0 else f"exited {rc}"
        tail = _tail(log_path)
        record.update(end=time.time(), returncode=rc, wall_seconds=result["wall_seconds"])
        _write_json(record_path, record)
        raise ShardError(f"octolod build {why} on {host} (log {log_path})" + (f":\n{tail}" if tail else ""))
    record.update(end=time.time(), returncode=rc, wall_seconds=result["wall_seconds"], status=result["status"])
    _write_json(record_path, record)
    return result


def read_attempts(attempts_dir: str) -> list[dict]:
    """The attempt records of one shard, oldest first (driver side)."""
    out = []
    try:
        names = sorted(n for n in os.listdir(attempts_dir) if n.endswith(".json"))
    except FileNotFoundError:
        return out
    for n in names:
        try:
            with open(os.path.join(attempts_dir, n)) as f:
                out.append(json.load(f))
        except (OSError, ValueError):
            continue
    return out
