"""The noise benchmark's execution: one run in a worker, and one path for every executor.

:func:`run_one` executes a :class:`~itg_vision.bench.sweep.RunSpec` anywhere (it builds its own
World and rig: nothing is shared but the spec). :func:`results` feeds specs to any
``concurrent.futures.Executor`` and yields each spec with its row as runs finish: the local
process pool (:func:`local_executor`; workers die with their parent, however it dies), the
calling process (``workers == 1``) and a Dask cluster (:func:`dask_executor`, the client's
``get_executor()``) all go through it.
"""

from __future__ import annotations

import os
import sys
import traceback
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait

from ..errors import NothingInReach, UserError
from .store import make_row
from .sweep import RIG_ANGLE_DEG, RIG_SHIFT_MM, RunSpec, calibrated_rig_path, run_config


def run_one(spec: RunSpec) -> dict:
    """Execute one spec (in a worker); return its results row, or ``{'run_id', 'error'}``.

    A run whose start-up measurement fails (the LEDs measured in too few looks), or whose
    simulated arm reaches no set point (links made longer: the one-link arm reaches only its
    circle), is a row of its own, ``no_start`` saying why (an outcome of its condition, the
    same at every retry); a `UserError` (the input stops the run: a rule's step that is not
    finite) is an error row marked ``user_error``, with no traceback; any other exception is an
    error, retried by the next resume.

    Builds its own World (PyBullet clients are per process) and, for ``rig-perturbed``, its own
    perturbed rig in memory: nothing is shared with the caller but the spec.
    """
    from ..camera import Rig, default_rig_path, perturbed
    from ..identify import StartUpFailed
    from ..runner import execute, prepare

    try:
        rig_path, rig = None, None
        if spec.vision and spec.rig == "calibrated":
            rig_path = str(calibrated_rig_path(spec.arm))
        elif spec.vision and spec.rig in ("perturbed", "perturbed-cams"):
            true_path = default_rig_path(spec.arm)
            rig = perturbed(Rig.from_yaml(true_path), spec.seed, angle_deg=RIG_ANGLE_DEG,
                            shift_mm=RIG_SHIFT_MM, each_camera=spec.rig == "perturbed-cams",
                            true_rig=true_path)
        prep = prepare(run_config(spec, rig_path), estimate_rig=rig)
        _, s = execute(prep)
    except (StartUpFailed, NothingInReach) as exc:
        why = str(exc).strip().splitlines() or [type(exc).__name__]
        return make_row(spec, None, no_start=why[0])
    except UserError as exc:  # the user's input stopped it (a rule's step not finite): the same
        # at every retry, and its one line says what to fix; no traceback
        return {"run_id": spec.run_id, "error": str(exc).splitlines()[0], "user_error": True}
    except Exception as exc:  # noqa: BLE001 - reported per run, the sweep goes on
        return {"run_id": spec.run_id, "error": f"{type(exc).__name__}: {exc}".splitlines()[0],
                "traceback": traceback.format_exc()}  # where it failed: a bug's one clue
    return make_row(spec, s)


def results(executor: Executor, specs, in_flight: int):
    """Yield ``(spec, row)`` as the runs of ``specs`` finish on ``executor``.

    At most ``in_flight`` runs are submitted at a time (the rest wait here), so that an
    interruption has little to cancel and an inline executor yields each row as it is made.
    A run whose worker died yields an error row (reported per run), never an exception.
    """
    todo = iter(specs)
    pending: dict[Future, RunSpec] = {}

    def fill() -> None:
        while len(pending) < max(1, in_flight):
            spec = next(todo, None)
            if spec is None:
                return
            fut = executor.submit(run_one, spec)
            pending[fut] = spec
            if fut.done():  # an inline executor ran it already: hand its row over first
                return

    fill()
    while pending:
        done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
        for fut in [f for f in pending if f in done]:  # in the order submitted
            spec = pending.pop(fut)
            yield spec, _outcome(spec, fut)
        fill()


def _outcome(spec: RunSpec, future) -> dict:
    """A finished future's row, or an error row when its worker died (reported per run): its
    message on one line (failures.log holds a line per run; Dask's error for a worker without
    the package takes four), every word kept."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - a dead or lost worker
        return {"run_id": spec.run_id, "error": " ".join(f"{type(exc).__name__}: {exc}".split())}


class InlineExecutor(Executor):
    """``workers == 1``: each submitted call runs at once in this process."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - handed to the future like a pool does
            fut.set_exception(exc)
        return fut


def _exit_with_parent() -> None:
    """Pool initializer: end this worker as soon as its parent dies, however it dies.

    A pool's workers otherwise outlive a parent killed by SIGKILL (they wait forever on the call
    queue, whose write end they hold themselves; the resource tracker lives as long as they do;
    cpython#111873). A daemon thread waits on the parent sentinel that ``spawn`` hands every
    child (a pipe closed by the kernel when the parent exits) and then ``os._exit`` s.
    """
    import multiprocessing
    import threading

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def local_executor(workers: int) -> Executor:
    """A spawn process pool of ``workers`` whose workers exit when this process dies (even by
    SIGKILL, see :func:`_exit_with_parent`), or the calling process when ``workers == 1``."""
    if workers <= 1:
        return InlineExecutor()
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_exit_with_parent)


def check_scheduler_address(address: str) -> None:
    """``[tcp|tls|ws|wss://]HOST:PORT``, port 1..65535, or a `UserError` naming --scheduler.

    Checked before a Dask Client is made: one built on a malformed address raises, and the
    half-made Client then prints a traceback and hangs 10 s when garbage-collected.
    """
    import re

    m = re.fullmatch(r"(?:(tcp|tls|ws|wss)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", address)
    if not m or not 1 <= int(m.group(3)) <= 65535:
        raise UserError(f"--scheduler {address}: expected tcp://HOST:PORT (port 1..65535)")


def check_scheduler_answers(address: str, timeout_s: float) -> None:
    """Ask what listens at ``address`` who it is (Dask's ``identity``), within ``timeout_s`` to
    connect and as long again for the answer: a `UserError` naming --scheduler unless a Dask
    scheduler answers.

    Asked before a Client is made: a Client whose connection is accepted but not answered (a
    dashboard's HTTP port) waited for ever, and one that another service or a Dask worker
    answered failed, then printed a traceback and hung 10 s when garbage-collected.
    """
    import asyncio

    from distributed.comm import connect

    async def identity():
        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(identity(), 2 * timeout_s))
    except TimeoutError:  # connected, and no answer: not Dask's protocol
        raise UserError(f"--scheduler {address}: no Dask scheduler answered within "
                        f"{2 * timeout_s:g} s (the dashboard's port, or another service?)") from None
    except OSError as exc:  # refused, unreachable, no such host
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UserError(f"--scheduler {address}: cannot connect ({msg})") from None
    except Exception as exc:  # noqa: BLE001 - an answer that is not Dask's (MemoryError, ...)
        raise UserError(f"--scheduler {address}: what answered is not a Dask scheduler "
                        f"({type(exc).__name__})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise UserError(f"--scheduler {address}: "
                        + (f"a Dask {kind} answered, not the scheduler (give the scheduler's "
                           "address)" if isinstance(kind, str) else "what answered is not a Dask "
                           "scheduler"))


def dask_executor(address: str, timeout_s: float = 5.0) -> tuple[Executor, int, object]:
    """The Dask cluster at ``address`` as a ``concurrent.futures`` executor (workers must be
    able to import itg_vision); returns ``(executor, threads, client)``."""
    check_scheduler_address(address)  # a Client that fails on a bad address hangs in __del__
    try:
        from distributed import Client
    except ImportError:
        raise UserError("--scheduler needs dask.distributed: pip install 'itg_vision[cluster]'") from None
    check_scheduler_answers(address, timeout_s)  # nor is one made for what is no scheduler
    try:
        client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError (bad address)
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UserError(f"--scheduler {address}: cannot connect ({msg})") from None
    workers = client.scheduler_info().get("workers", {})
    if not workers:  # Dask queues the runs until one joins: say why nothing moves
        print(f"note: the scheduler at {address} has no workers yet: the sweep waits for them "
              f"(start them with `dask worker {address}`)", file=sys.stderr)
    threads = max(1, sum(w.get("nthreads", 1) for w in workers.values()))
    return client.get_executor(pure=False), threads, client


def shutdown(executor: Executor, cancel: bool = False, client=None) -> None:
    """Stop ``executor``; ``cancel`` (an interruption) also stops the runs in flight (their rows
    were not written). A Dask executor stops with its ``client``."""
    if client is not None:
        client.close()
        return
    if cancel:
        for proc in list((getattr(executor, "_processes", None) or {}).values()):
            proc.terminate()
    # wait even when cancelled (the workers are gone, so the pool's manager thread ends at once):
    # a manager thread still running at exit can close its wake-up pipe between the exit hook's
    # check and its write, a traceback after "interrupted" (EBADF; a CPython race, gh-125451)
    executor.shutdown(wait=True, cancel_futures=cancel)
