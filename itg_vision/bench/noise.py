"""python -m itg_vision.bench noise: the noise-robustness benchmark (the command).

ITG fed by vision against the baselines, on the same runs, under named conditions (centroid
noise, LED dropout, the rig the estimator believes, kinematic model error, and a few
combinations). Writes to ``--out``: ``results.csv`` and ``sweep.json`` (:mod:`.store`: resume,
fsync, repair), ``report.md`` and plots (:mod:`.report`), ``failures.log`` when runs failed.
The sweep is defined in :mod:`.sweep` and runs through one ``concurrent.futures`` path
(:mod:`.execute`) on a local process pool (``--workers``) or a Dask cluster (``--scheduler``).
This module parses, calls and prints.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from .. import outputs
from ..arm import arm_names
from ..errors import ArgumentParser, UserError, at_least_one, exit_status, points_arg, run_main
from ..inputs import is_pipe
from ..options import add_rule_options, labels, rule_params
from ..trajectory import names_a_csv_file
from .execute import (check_scheduler_address, dask_executor, local_executor, results,
                      shutdown)
from .report import DEFAULT_PLOT_METRICS, PLOT_METRICS, write_report
from .store import (Results, check_sweep_file, code_warning, definition_hash, params_cell,
                    LOCK, record_sweep_file, started, sweep_lock)
from .sweep import (ALL_CONTROLLERS, CONDITIONS, FILES_ARM, FULL_SEEDS, MAX_SEEDS, QUICK,
                    SWEEPS, TRAJECTORIES, RunSpec, _parse_names, build_sweep, rules_controllers,
                    seed_count, span_notes, trajectory_label, user_rules)

#: The name this benchmark writes into its output folder's manifest.
COMMAND = "bench noise"


def check_out(out: Path, command: str = COMMAND) -> Path:
    """Refuse an ``--out`` the benchmark ``command`` must not write into (`UserError`, writes
    nothing); return its path.

    Allowed: a new path, an empty folder, or a folder this benchmark made (its manifest, or a
    ``sweep.json`` written by an earlier version): it resumes there (no ``--force``). Anything else (a file, a
    folder of other things, another command's output) is refused: report.md and the plots
    would be written over whatever is there. The folder must be writable.
    """
    path = outputs.check_path(out)
    if path.exists() and not path.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder")
    if path.is_dir() and any(p.name != LOCK for p in path.iterdir()):  # a lock alone: made here
        made = outputs.read_manifest(path)
        if made is not None and made.get("command") != command:
            raise UserError(f"--out {out}: holds the output of `{made.get('command')}`; choose "
                            "another --out")
        if made is None and not (path / "sweep.json").is_file():
            raise UserError(f"--out {out}: is a folder this benchmark did not make; choose "
                            "another --out")
    outputs.probe_folder(path)
    return path


def keep_edits(out: Path) -> None:
    """Keep aside (``report.replaced-1.md``, ...: :func:`outputs.keep_aside`) each file a run of
    this benchmark wrote into ``out`` and the user changed since (its manifest's digests), so
    that writing it again loses nothing of theirs."""
    made = outputs.read_manifest(out)
    for name in outputs.edited(out, made) if made is not None else []:
        outputs.keep_aside(out / name, f"{out / name} was changed since the benchmark wrote it")


def keep_theirs(out: Path):
    """A function of a file's name in ``out`` that keeps it aside (:func:`outputs.keep_aside`)
    if it is there and no run of this benchmark wrote it (its manifest, read once here, has no
    digest of it): a file of the user's, about to be written over or deleted."""
    recorded = outputs.recorded_digests(outputs.read_manifest(out))

    def keep(name: str) -> None:
        path = out / name
        if (path.exists() or path.is_symlink()) and name not in recorded:
            outputs.keep_aside(path, f"{path} is not a file the benchmark wrote")

    return keep


def record_written(out: Path, command: str, names: list[str]) -> None:
    """The manifest of ``out``, with the digests of the files named that exist (what
    :func:`keep_edits` compares) and of those an earlier run wrote that are still as it wrote
    them (a plot of other ``--plot-metrics``: the benchmark's, not the user's)."""
    earlier = outputs.recorded_digests(outputs.read_manifest(out))
    kept = {n: h for n, h in outputs.digests(out, list(earlier)).items() if h == earlier[n]}
    written = [n for n in names if (out / n).is_file()]
    outputs.write_json(out / outputs.MANIFEST, outputs.manifest(
        command, digests={**kept, **outputs.digests(out, written)}))


def command_line(name: str, argv: list[str]) -> str:
    """What reruns ``python -m itg_vision.bench NAME`` with ``argv`` (less ``--quiet``), for
    the reports to print: quoted, so that a path with a space reruns as it ran."""
    return f"python -m itg_vision.bench {name} {shlex.join(a for a in argv if a != '--quiet')}".strip()


def build_parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(
        prog="python -m itg_vision.bench noise",
        description="Noise-robustness benchmark: ITG (the paper's rules and ITG+) fed by vision "
                    "against the same rules fed by the nominal model, open-loop IK and a "
                    "vision-fed Jacobian tracker, under centroid noise, LED "
                    "dropout, rig errors and kinematic model errors. Writes results.csv, "
                    "report.md and plots to --out; rerun with the same --out to resume. "
                    "Pool workers exit when this process dies, however it dies.")
    ap.add_argument("--out", default="runs/bench-noise", metavar="DIR",
                    help="output folder (default %(default)s; --quick: runs/bench-noise-quick; "
                         "--sweep S: runs/bench-noise[-quick]-S; your --rules and --trajectories "
                         "files' stems, an --arm other than two-link and the rule parameters the "
                         "runs take are added to its name); a folder this benchmark made (rerun "
                         "to resume), an empty or a new one")
    ap.add_argument("--sweep", default="robustness", choices=tuple(SWEEPS),
                    help="robustness (default: every condition, 4 trajectories, "
                         f"{FULL_SEEDS} seeds), start-tie (the three-link arm from its "
                         "straight-up start, links +0/2/5 %%, 40 seeds: how often it diverges), "
                         "itg-plus or itg-plus-three-link (issue 13's targets; see "
                         "`bench itg-plus`)")
    ap.add_argument("--plot-metrics", metavar="A,B,...", default=",".join(DEFAULT_PLOT_METRICS),
                    help="what the plots show, any of " + ", ".join(PLOT_METRICS)
                         + " (default %(default)s)")
    ap.add_argument("--quick", action="store_true",
                    help=f"reduced sweep (< 2 min on 2 cores): {QUICK['trajectories'][0]} with "
                         f"{QUICK['points']} points, {QUICK['seeds']} seeds, conditions "
                         + ", ".join(QUICK["conditions"]).replace("%", "%%"))
    ap.add_argument("--seeds", type=seed_count, metavar="K",
                    help=f"seeds per cell, 1..{MAX_SEEDS} (default {FULL_SEEDS}; --quick "
                         f"{QUICK['seeds']})")
    ap.add_argument("--workers", type=at_least_one, metavar="N",
                    help="local worker processes (default: the number of CPUs; 1 = this process; "
                         "not with --scheduler)")
    ap.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="run on this Dask distributed scheduler instead of a local pool "
                         "(pip install 'itg_vision[cluster]')")
    ap.add_argument("--conditions", metavar="A,B,...",
                    help="only these conditions (see --list)")
    ap.add_argument("--controllers", metavar="A,B,...",
                    help="only these controllers: " + ", ".join(ALL_CONTROLLERS))
    ap.add_argument("--rules", action="append", default=[], metavar="FILE",
                    help="also run this rule base (a .rules file, or a shipped name) as two "
                         "controllers, STEM-vision and STEM-model, on the sweep's trajectories "
                         "of the arms it fits, beside the sweep's controllers (or those "
                         "--controllers names); repeat for more")
    add_rule_options(ap, " in your --rules files, not the shipped controllers'")
    ap.add_argument("--trajectories", metavar="A,B,...",
                    help="only these trajectories: " + ", ".join(TRAJECTORIES)
                         + "; or your own CSV files (a name ending in .csv or holding a folder "
                           "separator), tracked by the arm --arm names")
    ap.add_argument("--arm", metavar="NAME|FILE.yaml",
                    help="the arm that tracks the trajectory files given to --trajectories: "
                         f"{', '.join(arm_names())} or an arm file, whose benchmark: limits "
                         f"the runs take (default {FILES_ARM}; the benchmark's own trajectories "
                         "keep theirs)")
    ap.add_argument("--points", type=points_arg, metavar="N",
                    help="set points per lap of the named trajectories ellipse-t1, ellipse-t2, "
                         f"abcd and line-ab-reach (default: theirs; --quick {QUICK['points']}); "
                         "files (yours, peanut, helix, ...) keep their own")
    ap.add_argument("--limit", type=int, metavar="N",
                    help="run at most N of the remaining runs this time (the rest on a rerun)")
    ap.add_argument("--list", action="store_true",
                    help="list the controllers, conditions and trajectories (your --rules and "
                         "--trajectories files too, checked as a run checks them) and the "
                         "sweep's size; run nothing")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)

    def body() -> int:
        args = build_parser().parse_args(argv)
        if args.scheduler is not None:  # '' too: an unset variable is no local pool
            check_scheduler_address(args.scheduler)
            if args.workers is not None:
                raise UserError("--workers: sizes the local pool, which --scheduler replaces "
                                "(the cluster's workers run the sweep)")
        conds = _parse_names(args.conditions, CONDITIONS, "conditions", "condition")
        mine = [name for given in args.rules for name in rules_controllers(given)]
        ctrls = _parse_names(args.controllers, [*ALL_CONTROLLERS, *mine], "controllers",
                             "controller")
        plot_metrics = _parse_names(args.plot_metrics, PLOT_METRICS, "plot-metrics", "metric")
        trajs = _parse_names(args.trajectories, TRAJECTORIES, "trajectories", "trajectory",
                             files=names_a_csv_file)
        if args.limit is not None and args.limit < 0:
            raise UserError(f"--limit: must be >= 0, got {args.limit}")
        params = rule_params(args)  # checked as run checks them
        piped = next(((option, p) for option, given in (("--arm", [args.arm]),
                                                         ("--rules", args.rules),
                                                         ("--trajectories", trajs or ()))
                      for p in given if p is not None and is_pipe(p)), None)
        if piped:
            raise UserError(f"{piped[0]} {piped[1]}: a pipe, which the sweep cannot read again "
                            "(each run reads its input files afresh, in a worker process): "
                            "give a file")
        arm = FILES_ARM if args.arm is None else args.arm
        specs = build_sweep(quick=args.quick, seeds=args.seeds, conditions=conds,
                            controllers=ctrls, trajectories=trajs, points=args.points,
                            sweep=args.sweep, rules=tuple(args.rules), arm=arm,
                            rule_params=params)  # checks the arm file, given or not
        if args.arm is not None and not any(map(names_a_csv_file, trajs or ())):
            raise UserError(f"--arm {args.arm}: applies to trajectory files given to "
                            "--trajectories, and none is given (the benchmark's own "
                            "trajectories keep their arms)")
        if mine and not any(s.controller in mine for s in specs):
            raise UserError(f"--controllers: names none of your rule bases' controllers "
                            f"({', '.join(mine)}), so --rules would run nowhere")
        if args.points is not None and all(s.points is None for s in specs):
            paths = dict.fromkeys(trajectory_label(s.trajectory) for s in specs)
            raise UserError("--points: applies to the named trajectories only (ellipse-t1, "
                            f"ellipse-t2, abcd, line-ab-reach); {', '.join(paths)} keep their "
                            "files' set points")
        for note in span_notes(specs):
            print(note, file=sys.stderr)
        if args.list:  # after every check: a file the sweep would refuse is refused here
            print("\n".join(listing(specs, args.rules, trajs or (), arm, params)))
            return 0
        out = outputs.check_path(args.out)  # the text: '' is the empty-path error, not '.'
        if args.out == build_parser().get_default("out"):
            # every sweep a folder of its own, none another command's (bench itg-plus's)
            out = Path("runs/bench-noise" + "-quick" * args.quick
                       + ("" if args.sweep == "robustness" else f"-{args.sweep}"))
            # the parameters the runs take (an S equal to the servo limit a file binds S to
            # is dropped: those runs are the ones without it) and any arm but the default
            # name (an arm file is another arm, whatever its name)
            taken = {k: v for s in specs for k, v in s.rule_params.items()}
            yours = [Path(r).stem for r in args.rules] + [
                trajectory_label(t) for t in trajs or () if names_a_csv_file(t)] + (
                [Path(arm).stem] if arm != FILES_ARM else []) + labels(taken)
            if yours:  # a folder of its own: the sweep without your files keeps its results
                out = out.with_name(f"{out.name}-" + "-".join(yours))
        options = {"sweep": args.sweep, "quick": args.quick, "seeds": args.seeds,
                   "conditions": args.conditions,
                   "controllers": args.controllers, "trajectories": args.trajectories,
                   "points": args.points, "rules": args.rules or None, "gain": args.gain,
                   "step": args.step, "tolerance": args.tolerance}
        status, _ = run_sweep(specs, out, options, command_line("noise", argv),
                              workers=args.workers, scheduler=args.scheduler, limit=args.limit,
                              quiet=args.quiet, plot_metrics=plot_metrics)
        return status

    return run_main(body)


def listing(specs: list[RunSpec], rules, trajectories, arm: str, params: dict[str, float]
            ) -> list[str]:
    """``--list``: the controllers, conditions and trajectories (the user's rule bases', with
    the rule parameters ``params``, and files' too, as the sweep ``specs`` runs them), and the
    sweep's size."""
    arms = list(dict.fromkeys(s.arm for s in specs))
    users = user_rules(rules, arms, params)
    files = [t for t in trajectories if names_a_csv_file(t)]
    cost = sum(s.cost_s() for s in specs)
    return (["controllers: " + ", ".join(ALL_CONTROLLERS)]
            + [f"  yours (--rules): {', '.join(u.controllers)}: {u.rules}, on the "
               f"{' and '.join(u.arms)} arm" + (f", {params_cell(dict(u.params))}" if u.params
                                                else "") for u in users]
            + ["conditions:  " + ", ".join(CONDITIONS),
               "trajectories: " + ", ".join(TRAJECTORIES)]
            + [f"  yours (--trajectories): {trajectory_label(t)}: {Path(t).resolve()}, on the "
               f"{arm} arm" for t in files]
            + [f"sweep: {len(specs)} runs ({sum(s.vision for s in specs)} with rendering), "
               f"~{cost / 60:.1f} min of work"])


def run_sweep(specs: list[RunSpec], out: Path, options: dict, command: str, *,
              workers: int | None = None, scheduler: str | None = None, limit: int | None = None,
              quiet: bool = False, plot_metrics=DEFAULT_PLOT_METRICS) -> tuple[int, list[dict]]:
    """Run the sweep ``specs`` into ``out`` (resuming what it holds), write its report, and
    return the exit status (0; 1 when runs failed, each in ``failures.log``; 2 when the user's
    input stopped some, e.g. a rule's step that is not finite) and the rows
    ``results.csv`` holds. A run that did not start (its start-up measurement found the LEDs in
    too few looks) is a row, not a failure: the report names it. ``options`` are recorded in
    ``sweep.json``; ``command`` (what reproduces it) heads the report.
    Raises :class:`UserError` (before writing anything) for an ``--out`` that is not this
    sweep's."""
    check_out(out)
    definition = definition_hash(specs)
    store = Results(out / "results.csv")
    # every refusal comes before any write: a foreign --out keeps every row
    check_sweep_file(out, definition, specs, store)
    client = None
    if scheduler is not None:
        executor, n_workers, client = dask_executor(scheduler)
    else:
        n_workers = workers or os.cpu_count() or 1
        executor = local_executor(n_workers)
    try:  # a second sweep into this --out at once is refused
        with sweep_lock(out):
            return _run_locked(specs, out, options, command, definition, executor, n_workers,
                               client, where=f"Dask at {scheduler}" if scheduler is not None else
                               f"{n_workers} local worker(s)", limit=limit, quiet=quiet,
                               plot_metrics=plot_metrics)
    finally:  # after the runs, and after a refusal (stopping a stopped executor is a no-op)
        shutdown(executor, client=client)


def _run_locked(specs, out, options, command, definition, executor, n_workers, client, *,
                where, limit, quiet, plot_metrics) -> tuple[int, list[dict]]:
    """:func:`run_sweep` under its --out's lock."""
    n_vision = sum(s.vision for s in specs)
    store = Results(out / "results.csv")  # as the lock found it (a sweep may just have ended)
    if outputs.read_manifest(out) is None:  # an earlier run's keeps its digests (keep_edits)
        outputs.write_json(out / outputs.MANIFEST, outputs.manifest(COMMAND))
    record_sweep_file(out, definition, options, specs)
    store.repair()
    for msg in store.problems + [m for m in [code_warning(store)] if m]:
        print(f"warning: {msg}", file=sys.stderr)
    todo = [s for s in specs if s.run_id not in store.rows]
    if limit is not None:
        todo = todo[:limit]
    todo_cost = sum(s.cost_s() for s in todo)
    print(f"noise sweep {definition}: {len(specs)} runs ({n_vision} with rendering), "
          f"{len(store.rows)} already done, {len(todo)} to run on {where}: "
          f"estimated {todo_cost / n_workers / 60:.1f} min", file=sys.stderr)
    failures: dict[str, str] = {}
    yours: set[str] = set()  # the failed runs your input stopped (a rule's step not finite)

    def stored() -> int:  # runs of this sweep with their row in results.csv
        return sum(1 for s in specs if s.run_id in store.rows)

    try:
        _run_all(executor, 2 * n_workers, todo, store, failures, yours, quiet)
    except BaseException as exc:
        shutdown(executor, cancel=True, client=client)
        if isinstance(exc, KeyboardInterrupt):  # counted on disk, what a resume will find:
            # Ctrl-C may land between a row's fsync and its entry in the store's memory
            try:
                on_disk = Results(store.path).rows
            except UserError:  # unreadable now: what this process stored
                on_disk = store.rows
            done = sum(1 for s in specs if s.run_id in on_disk)
            print(f"\n{done} of {len(specs)} runs are in {out / 'results.csv'}; the same "
                  "command runs the rest", file=sys.stderr)
        raise
    shutdown(executor, client=client)
    store.reorder([s.run_id for s in specs])  # the sweep's order, not the order runs finished
    rows = list(store.rows.values())
    keep_edits(out)
    theirs = keep_theirs(out)
    plots = write_report(out, rows, specs, command, failures, plot_metrics,
                         keep=lambda path: theirs(path.name))
    theirs("failures.log")  # written or deleted below: a file of the user's is kept
    failures = {**_earlier_failures(out / "failures.log", store, todo), **failures}
    if failures:
        outputs.write_text(out / "failures.log",
                           "".join(f"{k}\t{v}\n" for k, v in failures.items()))
    elif (out / "failures.log").exists():  # every run it listed has its row now
        (out / "failures.log").unlink()
    record_written(out, COMMAND, ["report.md", "failures.log", *(p.name for p in plots)])
    done = stored()
    gone = len(rows) - len(started(rows))
    print(f"{done} of {len(specs)} runs in {out / 'results.csv'}"
          + (f" ({gone} did not start: see the report)" if gone else "")
          + f"; report {out / 'report.md'}; {len(plots)} plots", file=sys.stderr)
    if yours:  # a retry fails the same way: what to fix, in one line
        first = failures[next(k for k in failures if k in yours)]
        print(f"error: {len(yours)} of {len(failures)} failed runs were stopped by your input "
              f"(see {out / 'failures.log'}; first: {first}); fix it, then the same command "
              "reruns every failed run", file=sys.stderr)
        return 2, rows
    if failures:
        print(f"error: {len(failures)} runs failed (see {out / 'failures.log'}); rerun the "
              "same command to retry them", file=sys.stderr)
        return 1, rows
    return 0, rows


def _earlier_failures(path: Path, store: Results, tried: list[RunSpec]) -> dict[str, str]:
    """The failures an earlier attempt listed in ``path`` whose runs were not tried again now
    (``--limit``) and still have no row."""
    if not path.exists():
        return {}
    done = {s.run_id for s in tried} | set(store.rows)
    lines = (line.split("\t", 1) for line in path.read_text(errors="replace").splitlines())
    return {p[0]: p[1] for p in lines if len(p) == 2 and p[0] not in done}


def _run_all(executor, in_flight: int, todo: list[RunSpec], store: Results, failures: dict,
             yours: set, quiet: bool) -> None:
    """Run ``todo`` on ``executor`` and store each row as its run finishes (or note its
    failure in ``failures``, and in ``yours`` when the user's input stopped it), with a
    progress bar weighted by the runs' estimated costs."""
    from ..progress import progress

    weight = {s.run_id: max(1, round(100 * s.cost_s())) for s in todo}  # estimated cost, 10 ms
    bar = progress(sum(weight.values()), "noise sweep", quiet=quiet or not todo, unit="",
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix} [{elapsed}<{remaining}]")
    n_done = 0
    bar.set_postfix_str(f"0/{len(todo)} runs")
    try:
        for spec, res in results(executor, todo, in_flight):
            if "error" in res:
                failures[spec.run_id] = f"{spec.controller} {spec.condition} " \
                                        f"{trajectory_label(spec.trajectory)} " \
                                        f"seed {spec.seed}: {res['error']}"
                bar.write(f"run failed: {failures[spec.run_id]}", file=sys.stderr)
                if res.get("user_error"):
                    yours.add(spec.run_id)
                if res.get("traceback"):  # the run's own error (not a lost worker): where
                    bar.write(res["traceback"].rstrip(), file=sys.stderr)
            else:
                store.append(res)
            n_done += 1
            bar.set_postfix_str(f"{n_done}/{len(todo)} runs")  # before the line update prints
            bar.update(weight[spec.run_id])
    finally:
        bar.close()


if __name__ == "__main__":
    sys.exit(exit_status(main()))

