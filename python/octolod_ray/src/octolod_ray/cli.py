"""``octolod-ray``: run a sharded octolod build on a Ray cluster.

    octolod-ray build IN -o STORE --shards N [--address auto|ADDR] [--work DIR]
        [--mem 256M] [--octolod PATH] [--retries 3] [--json REPORT.json]
        [--quiet] [--force] [-- PLAN FLAGS...]

The driver runs ``octolod plan`` itself, then one Ray task per shard (largest
first) that runs ``octolod build --plan --shard`` on some node, then ``octolod
merge`` itself. Every path lives on a filesystem that all nodes share (the
work directory, the input, the store); tasks pass paths, never data.

Running the same command again with the same work directory resumes: the plan
is reused while the input and the options are unchanged (a plan the binary
calls stale is made again), shards already built are skipped by the binary,
and a store this work directory already merged is left as it is.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from . import __version__
from . import shard as shard_task

PROG = "octolod-ray"
#: Longest Ray temp dir that keeps Ray's socket paths under the AF_UNIX limit
#: (TEMP/session_<date>_<time>_<us>_<pid>/sockets/plasma_store.N < 108 bytes).
_MAX_RAY_TEMP = 36


class Fail(Exception):
    """An error that ends the run with exit status 1 and this message."""


def _err(msg: str) -> None:
    print(f"{PROG}: {msg}", file=sys.stderr)


def _mib(n: int | None) -> str:
    return "-" if not n else f"{n / 2**20:,.0f} MiB"


def _write_json(path: str, obj) -> None:
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2, sort_keys=False)
        f.write("\n")
    os.replace(tmp, path)


def _read_json(path: str):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


# --------------------------------------------------------------------------
# arguments


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Build an octolod store from a huge mesh as shards on a Ray cluster "
        "(plan and merge run here, one Ray task per shard; all paths on a shared filesystem).",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    b = sub.add_parser(
        "build",
        help="plan, build every shard as a Ray task, merge",
        description="Plan (here), build every shard as a Ray task (largest first), merge (here). "
        "Flags after `--` go to `octolod plan` (e.g. -- --leaf-tris 8192).",
        usage="%(prog)s IN -o STORE --shards N [options] [-- PLAN FLAGS...]",
    )
    b.add_argument("input", metavar="IN", help="input mesh (on the shared filesystem)")
    b.add_argument("-o", "--output", metavar="STORE", required=True, help="store directory to write")
    b.add_argument("--shards", type=int, required=True, metavar="N", help="number of shards to plan")
    b.add_argument(
        "--address",
        metavar="auto|ADDR",
        help="connect to this existing Ray cluster (default: $RAY_ADDRESS, else start a local "
        "one for this run only); never starts a cluster manager",
    )
    b.add_argument(
        "--work",
        metavar="DIR",
        help="work directory on the shared filesystem: plan, shards, logs (default: STORE.work); "
        "the same DIR again resumes",
    )
    b.add_argument("--mem", metavar="SIZE", help="working-memory budget of each octolod process (e.g. 256M)")
    b.add_argument(
        "--octolod",
        metavar="PATH",
        default="octolod",
        help="the octolod binary (default: octolod on PATH); must exist at the same path on every node",
    )
    b.add_argument("--retries", type=int, default=3, metavar="N", help="Ray retries per shard (default 3)")
    b.add_argument("--cpus-per-shard", type=float, default=1, metavar="N", help="Ray CPUs each shard task takes (default 1)")
    b.add_argument("--num-cpus", type=int, metavar="N", help="CPUs of the local Ray instance (only without --address)")
    b.add_argument("--json", metavar="REPORT.json", help="write the timings report as JSON here")
    b.add_argument("--quiet", "-q", action="store_true", help="no progress, no table (errors only)")
    b.add_argument("--force", action="store_true", help="replace an existing STORE (passed to octolod merge)")
    b.add_argument(
        "--copy",
        action="store_true",
        help="copy the shards' packs into the store (passed to octolod merge; default: hard-linked in place)",
    )
    return p


def _split_extra(argv: list[str]) -> tuple[list[str], list[str]]:
    if "--" in argv:
        i = argv.index("--")
        return argv[:i], argv[i + 1 :]
    return argv, []


def _resolve_binary(name: str) -> str:
    if os.sep in name:
        path = os.path.abspath(name)
    else:
        found = shutil.which(name)
        if found is None:
            raise Fail(f"octolod binary `{name}` not found on PATH (give --octolod PATH)")
        path = os.path.abspath(found)
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        raise Fail(f"octolod binary {path} does not exist or is not executable (--octolod)")
    return path


# --------------------------------------------------------------------------
# running the binary here (plan, merge)


def _run_local(cmd: list[str], what: str) -> tuple[str, float]:
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True, errors="replace")
    except OSError as e:
        raise Fail(f"{what}: cannot run {cmd[0]}: {e}") from None
    dt = time.monotonic() - t0
    if p.returncode != 0:
        why = f"killed by signal {-p.returncode}" if p.returncode < 0 else f"exited {p.returncode}"
        msg = (p.stderr.strip() or p.stdout.strip())[-3000:]
        raise Fail(f"{what} failed ({' '.join(cmd[:2])} {why})" + (f":\n{msg}" if msg else ""))
    return p.stdout + p.stderr, dt


class Work:
    """The work directory's layout."""

    def __init__(self, root: str):
        self.root = root
        self.plan = os.path.join(root, "plan.json")
        self.plan_key = os.path.join(root, "plan-key.json")
        self.merged = os.path.join(root, "merged.json")
        self.lock = os.path.join(root, ".lock")

    def shards_of(self, plan_id: str) -> str:
        return os.path.join(self.root, "shards", plan_id)

    def run_dir(self, run_id: str) -> str:
        return os.path.join(self.root, "runs", run_id)


def _lock(work: Work):
    """One driver per work directory (best effort: flock)."""
    f = open(work.lock, "a+")
    try:
        import fcntl

        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except ImportError:
        pass
    except OSError:
        f.close()
        raise Fail(f"another {PROG} is using the work directory {work.root}") from None
    return f


def _plan_key(inp: str, args, extra: list[str]) -> dict:
    st = os.stat(inp)
    return {
        "input": inp,
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "shards": args.shards,
        "mem": args.mem,
        "plan_args": extra,
    }


def _valid_plan(plan) -> bool:
    try:
        return (
            plan.get("format") == "octolod-plan"
            and isinstance(plan.get("plan_id"), str)
            and len(plan["shards"]) > 0
            and all(isinstance(s["index"], int) for s in plan["shards"])
        )
    except (AttributeError, KeyError, TypeError):
        return False


def _safe_id(plan_id: str) -> str:
    return re.sub(r"[^0-9A-Za-z_.-]", "_", plan_id)[:80] or "plan"


def _make_plan(binary: str, inp: str, work: Work, key: dict, args, extra: list[str]) -> dict:
    cmd = [binary, "plan", inp, "-o", work.plan, "--shards", str(args.shards)]
    if args.mem:
        cmd += ["--mem", args.mem]
    cmd += extra + ["--quiet"]
    if os.path.exists(work.plan):
        cmd.append("--force")  # our own plan file, made for other options or an older input
    if os.path.exists(work.plan_key):
        os.remove(work.plan_key)
    _run_local(cmd, "plan")
    plan = _read_json(work.plan)
    if not _valid_plan(plan):
        raise Fail(f"plan: {work.plan} is not an octolod plan this driver understands")
    _write_json(work.plan_key, dict(key, plan_id=plan["plan_id"]))
    # Shards of earlier plans are of no use any more.
    shards_root = os.path.join(work.root, "shards")
    if os.path.isdir(shards_root):
        for name in os.listdir(shards_root):
            if name != _safe_id(plan["plan_id"]):
                shutil.rmtree(os.path.join(shards_root, name), ignore_errors=True)
    return plan


def _store_stamp(store: str):
    try:
        st = os.stat(os.path.join(store, "store.json"))
    except OSError:
        return None
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _already_merged(work: Work, store: str, plan_id: str | None) -> bool:
    m = _read_json(work.merged)
    if not isinstance(m, dict) or m.get("store") != store:
        return False
    if plan_id is not None and m.get("plan_id") != plan_id:
        return False
    stamp = _store_stamp(store)
    return stamp is not None and m.get("store_json") == stamp


# --------------------------------------------------------------------------
# Ray


def _check_reachable(address: str) -> None:
    """Fail fast on a HOST:PORT where nothing listens (Ray itself retries
    for minutes); `auto` and ray:// addresses are left to Ray."""
    m = re.fullmatch(r"\[?([^\[\]/]+?)\]?:(\d+)", address)
    if not m:
        return
    try:
        socket.create_connection((m.group(1), int(m.group(2))), timeout=10).close()
    except OSError as e:
        raise Fail(f"no Ray cluster answers at {address}: {e}") from None


class RayRun:
    """Connects to a cluster (or starts a local Ray instance for this run)."""

    def __init__(self, args, work: Work, run_dir: str):
        self.address = args.address or os.environ.get("RAY_ADDRESS") or None
        if self.address == "local":
            self.address = None
        self.local = self.address is None
        if not self.local:
            _check_reachable(self.address)
        self._link = None
        if self.local:
            self._prepare_local_auth(work)
        import ray  # after the auth variables: Ray reads them when imported

        self.ray = ray
        self._route_ray_errors(os.path.join(run_dir, "ray-errors.log"), echo=not args.quiet)
        level = logging.ERROR if args.quiet else logging.WARNING
        if self.local:
            temp = os.path.join(work.root, "ray")
            os.makedirs(temp, exist_ok=True)
            if len(temp) > _MAX_RAY_TEMP:
                # Ray's sockets live under the temp dir and AF_UNIX paths are
                # short: point a short link at the directory inside WORK.
                self._link = os.path.join(tempfile.mkdtemp(prefix="olr-", dir="/tmp"), "r")
                os.symlink(temp, self._link)
                temp = self._link
            kwargs = dict(
                address="local",
                _temp_dir=temp,
                include_dashboard=False,
                object_store_memory=128 * 2**20,  # tasks pass paths, not data
                logging_level=level,
                log_to_driver=False,
            )
            if args.num_cpus:
                kwargs["num_cpus"] = args.num_cpus
        else:
            kwargs = dict(address=self.address, logging_level=level, log_to_driver=False)
        try:
            ray.init(**kwargs)
        except Exception as e:  # noqa: BLE001 - a connection or start-up failure
            self._unlink()
            where = "start a local Ray instance" if self.local else f"connect to the Ray cluster at {self.address}"
            raise Fail(f"cannot {where}: {type(e).__name__}: {e}") from None
        # Ship the task's module by value: workers need Ray and the binary,
        # not this package.
        ray.cloudpickle.register_pickle_by_value(shard_task)

    @staticmethod
    def _route_ray_errors(path: str, echo: bool):
        """Ray's driver prints the errors the cluster reports (a worker died,
        a task will be retried, with tracebacks) on stdout, where the table
        goes: keep them whole in the run's log, and echo their first lines
        on stderr unless --quiet. Our own report says what failed in the end."""
        try:
            import ray._private.worker as rw

            orig = rw.print_to_stdstream
        except (ImportError, AttributeError):
            return

        def route(data, ignore_prefix, _orig=orig):
            if data.get("pid") != "raylet" or data.get("is_err"):
                return _orig(data, ignore_prefix)
            lines = [str(x) for x in data.get("lines", [])]
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with open(path, "a") as f:
                    f.write(time.strftime("%H:%M:%S ") + "\n".join(lines) + "\n")
            except OSError:
                pass
            if echo:
                for text in lines:
                    first = text.strip().splitlines()[0] if text.strip() else ""
                    if first:
                        print(f"ray: {first[:300]}", file=sys.stderr, flush=True)

        rw.print_to_stdstream = route

    @staticmethod
    def _prepare_local_auth(work: Work):
        # Ray >= 2.5x turns token auth on for a new local instance and keeps
        # the token in ~/.ray; keep ours in the work directory instead.
        if any(v in os.environ for v in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")):
            return
        path = os.path.join(work.root, "ray-auth-token")
        if not os.path.exists(path):
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32))
        os.environ["RAY_AUTH_MODE"] = "token"
        os.environ["RAY_AUTH_TOKEN_PATH"] = path

    def describe(self) -> str:
        return "local Ray instance" if self.local else f"Ray cluster at {self.address}"

    def close(self):
        try:
            self.ray.shutdown()
        finally:
            self._unlink()

    def _unlink(self):
        if self._link:
            try:
                os.unlink(self._link)
                os.rmdir(os.path.dirname(self._link))
            except OSError:
                pass
            self._link = None


def _failure_text(e: BaseException) -> str:
    """One readable reason for a task that failed after its retries."""
    import ray.exceptions as rex

    if isinstance(e, rex.RayTaskError):
        cause = getattr(e, "cause", None)
        if cause is not None and type(cause).__name__ == "ShardError":
            return str(cause)
        if cause is not None:
            return f"{type(cause).__name__}: {cause}"
    if isinstance(e, rex.WorkerCrashedError):
        return "its worker process died (killed or crashed)"
    if isinstance(e, getattr(rex, "NodeDiedError", ())):
        return "its node died"
    first = str(e).strip().splitlines()
    return f"{type(e).__name__}" + (f": {first[0]}" if first else "")


class Progress:
    def __init__(self, total: int, enabled: bool):
        self.bar = None
        self.plain = False
        self.done = 0
        self.total = total
        if not enabled:
            return
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="shard", desc="shards", file=sys.stderr, dynamic_ncols=True)
        except ImportError:
            self.plain = True

    def step(self, line: str):
        self.done += 1
        if self.bar is not None:
            self.bar.set_postfix_str(line, refresh=False)
            self.bar.update(1)
        elif self.plain:
            print(f"[{self.done}/{self.total}] {line}", file=sys.stderr, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _run_shards(rr: RayRun, specs: list[dict], args, progress: Progress) -> list[dict]:
    ray = rr.ray
    task = ray.remote(
        num_cpus=args.cpus_per_shard,
        max_retries=args.retries,
        retry_exceptions=True,
    )(shard_task.build_shard)
    refs = {}
    for spec in specs:  # largest first: Ray dispatches in submission order
        refs[task.options(name=f"octolod-shard-{spec['index']}").remote(spec)] = spec
    results = []
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                spec = refs[ref]
                try:
                    res = ray.get(ref)
                except Exception as e:  # noqa: BLE001 - every failure is reported
                    res = {"index": spec["index"], "status": "failed", "error": _failure_text(e)}
                res = _with_attempts(res, spec)
                results.append(res)
                progress.step(_step_line(res))
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    return results


def _with_attempts(res: dict, spec: dict) -> dict:
    attempts = shard_task.read_attempts(spec["attempts_dir"])
    res = dict(res)
    res["attempts"] = max(len(attempts), res.get("attempt") or 0)
    res["attempt_log"] = [
        {
            k: a.get(k)
            for k in ("host", "node_id", "worker_pid", "start", "end", "returncode", "status", "wall_seconds", "log", "error")
            if a.get(k) is not None
        }
        for a in attempts
    ]
    if res["status"] == "failed" and attempts:
        res.setdefault("host", attempts[-1].get("host"))
        res.setdefault("log", attempts[-1].get("log"))
    return res


def _step_line(res: dict) -> str:
    i = res["index"]
    if res["status"] == "failed":
        return f"shard {i} failed"
    s = f"shard {i} {res['status']}"
    if res["status"] == "built":
        s += f" in {res['wall_seconds']:.1f} s on {res.get('host')}"
    return s


# --------------------------------------------------------------------------
# the build command


def _table(report: dict) -> str:
    rows = [("shard", "est. tris", "status", "tries", "wall s", "max RSS", "host")]
    for s in report["shards"]:
        rows.append(
            (
                str(s["index"]),
                f"{s.get('est_triangles', 0):,}",
                s["status"],
                str(s.get("attempts", "-")),
                f"{s['wall_seconds']:.2f}" if "wall_seconds" in s else "-",
                _mib(s.get("max_rss_bytes")),
                str(s.get("host") or "-"),
            )
        )
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    right = {0, 1, 3, 4, 5}
    lines = ["  ".join(v.rjust(w) if c in right else v.ljust(w) for c, (v, w) in enumerate(zip(r, widths))).rstrip() for r in rows]
    t = report["seconds"]
    lines.append(
        f"plan {t['plan']:.2f} s{' (reused)' if report['plan']['reused'] else ''}, "
        f"shards {t['shards']:.2f} s, merge {t['merge']:.2f} s"
        f"{' (already merged)' if report['merge']['skipped'] else ''}, total {t['total']:.2f} s"
    )
    return "\n".join(lines)


def build(args, extra: list[str]) -> int:
    t_start = time.monotonic()
    inp = os.path.abspath(args.input)
    store = os.path.abspath(args.output)
    work = Work(os.path.abspath(args.work or store + ".work"))
    if not os.path.isfile(inp):
        raise Fail(f"input {inp} not found")
    binary = _resolve_binary(args.octolod)
    say = (lambda *a: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    os.makedirs(work.root, exist_ok=True)
    lock = _lock(work)

    run_id = time.strftime("%Y%m%d-%H%M%S") + f"-{os.getpid()}"
    run_dir = work.run_dir(run_id)
    report = {
        "format": "octolod-ray-report",
        "version": 1,
        "octolod_ray": __version__,
        "input": inp,
        "store": store,
        "work": work.root,
        "run": run_id,
        "octolod": binary,
        "shards_asked": args.shards,
        "mem": args.mem,
        "plan_args": extra,
        "retries": args.retries,
        "ok": False,
        "plan": {"reused": False},
        "merge": {"skipped": False},
        "seconds": {"plan": 0.0, "shards": 0.0, "merge": 0.0, "total": 0.0},
        "shards": [],
    }

    def finish(ok: bool, error: str | None = None) -> None:
        report["ok"] = ok
        if error:
            report["error"] = error
        report["seconds"]["total"] = round(time.monotonic() - t_start, 3)
        _write_json(os.path.join(run_dir, "report.json"), report)
        if args.json:
            _write_json(os.path.abspath(args.json), report)

    rr = None
    try:
        if os.path.exists(store) and not args.force and not _already_merged(work, store, None):
            raise Fail(f"{store} exists (give --force to replace it)")

        # Ray first: a cluster that is not there fails the run before the plan's pass.
        rr = RayRun(args, work, run_dir)
        report["ray"] = {"address": rr.address or "local", "version": rr.ray.__version__}

        # 1. plan, here
        key = _plan_key(inp, args, extra)
        plan = _read_json(work.plan)
        saved = _read_json(work.plan_key)
        t0 = time.monotonic()
        if _valid_plan(plan) and isinstance(saved, dict) and saved.get("plan_id") == plan["plan_id"] and {
            k: saved.get(k) for k in key
        } == key:
            report["plan"]["reused"] = True
            say(f"plan {plan['plan_id']}: reused ({work.plan})")
        else:
            say(f"planning {args.shards} shards of {inp} ...")
            plan = _make_plan(binary, inp, work, key, args, extra)
        report["seconds"]["plan"] = round(time.monotonic() - t0, 3)

        # 2. the shards, as Ray tasks
        replanned = False
        while True:
            plan_id = plan["plan_id"]
            report["plan_id"] = plan_id
            report["shard_levels"] = plan.get("shard_levels")
            if os.path.exists(store) and not args.force and not _already_merged(work, store, plan_id):
                raise Fail(f"{store} exists (give --force to replace it)")
            est = {s["index"]: int(s.get("est_triangles", 0)) for s in plan["shards"]}
            order = sorted(plan["shards"], key=lambda s: -int(s.get("est_triangles", 0)))
            shard_root = work.shards_of(_safe_id(plan_id))
            os.makedirs(shard_root, exist_ok=True)
            specs = [
                {
                    "binary": binary,
                    "input": inp,
                    "plan": work.plan,
                    "index": s["index"],
                    "out_dir": os.path.join(shard_root, f"shard-{s['index']:04d}"),
                    "mem": args.mem,
                    "attempts_dir": os.path.join(run_dir, f"plan-{_safe_id(plan_id)}", f"shard-{s['index']:04d}"),
                }
                for s in order
            ]
            say(f"{len(specs)} shards on the {rr.describe()} (work {work.root})")
            t0 = time.monotonic()
            progress = Progress(len(specs), enabled=not args.quiet and sys.stderr.isatty())
            try:
                results = _run_shards(rr, specs, args, progress)
            finally:
                progress.close()
            report["seconds"]["shards"] = round(report["seconds"]["shards"] + time.monotonic() - t0, 3)
            by_index = {r["index"]: r for r in results}
            report["shards"] = []
            for spec in specs:
                r = by_index[spec["index"]]
                r["est_triangles"] = est.get(spec["index"], 0)
                r["dir"] = spec["out_dir"]
                report["shards"].append(r)
            if any(r["status"] == "stale" for r in results):
                if replanned:
                    raise Fail("the binary still calls the plan stale after planning again: is the input changing?")
                say("the input changed since the plan: planning again")
                t0 = time.monotonic()
                plan = _make_plan(binary, inp, work, _plan_key(inp, args, extra), args, extra)
                report["plan"]["reused"] = False
                report["seconds"]["plan"] = round(report["seconds"]["plan"] + time.monotonic() - t0, 3)
                replanned = True
                continue
            break

        failed = [r for r in report["shards"] if r["status"] == "failed"]
        if failed:
            lines = []
            for r in failed:
                n = r.get("attempts", 0)
                lines.append(f"shard {r['index']} failed after {n} attempt{'s' if n != 1 else ''}: {r['error']}")
            raise Fail("\n".join(lines) + f"\n{len(failed)} of {len(report['shards'])} shards failed; "
                       f"run the same command again to retry them (finished shards are kept in {work.root})")

        # 3. merge, here
        t0 = time.monotonic()
        if _already_merged(work, store, plan["plan_id"]):
            report["merge"]["skipped"] = True
            say(f"{store} already holds this plan's store: not merged again")
        else:
            say(f"merging {len(report['shards'])} shards into {store} ...")
            cmd = [binary, "merge", work.plan] + [s["dir"] for s in sorted(report["shards"], key=lambda s: s["index"])]
            cmd += ["-o", store]
            if args.mem:
                cmd += ["--mem", args.mem]
            cmd.append("--quiet")
            if args.force:
                cmd.append("--force")
            if args.copy:
                cmd.append("--copy")
            _run_local(cmd, "merge")
            _write_json(work.merged, {"plan_id": plan["plan_id"], "store": store, "store_json": _store_stamp(store)})
        report["seconds"]["merge"] = round(time.monotonic() - t0, 3)
        finish(True)
        if not args.quiet:
            print(_table(report))
            print(f"store: {store}")
        return 0
    except Fail as e:
        finish(False, str(e))
        if not args.quiet and report["shards"]:
            print(_table(report))
        raise
    except KeyboardInterrupt:
        finish(False, "interrupted")
        raise
    finally:
        if rr is not None:
            rr.close()
        lock.close()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    argv, extra = _split_extra(argv)
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command == "build":
        if args.shards < 1:
            parser.error("--shards must be at least 1")
        if args.retries < 0:
            parser.error("--retries must be at least 0")
        if args.cpus_per_shard <= 0:
            parser.error("--cpus-per-shard must be positive")
    try:
        if args.command == "build":
            return build(args, extra)
    except Fail as e:
        _err(str(e))
        return 1
    except KeyboardInterrupt:
        _err("interrupted")
        return 130
    return 2


if __name__ == "__main__":
    sys.exit(main())
