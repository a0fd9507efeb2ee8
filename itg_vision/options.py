"""The options of ``run``, by the RunConfig field each sets (an error names the option), and
those of a rule base's parameters f, S and w (``--gain``, ``--step``, ``--tolerance``), which
``run`` and ``bench noise`` share. Light to import (a command's ``--help`` and ``--list`` need
no simulator): the runner is imported only to check values given."""

from __future__ import annotations

import argparse

from .rules import PARAM_DEFAULTS, PARAM_FIELDS, PARAM_OF_FIELD

#: argparse dest -> the rules' name of the parameter (its RunConfig field: ``PARAM_FIELDS``).
RULE_OPTIONS = {"gain": "f", "step": "S", "tolerance": "w"}

#: RunConfig field -> the option that sets it (errors name the option).
OPTIONS = {"arm": "--arm", "links_mm": "--links", "trajectory": "--trajectory", "points": "--points",
           "controller": "--controller", "rules": "--rules", "gain_deg_per_mm": "--gain",
           "step_deg": "--step", "tolerance_mm": "--tolerance", "damping_mm": "--damping", "iterations": "--iterations",
           "max_step_deg": "--max-step", "laps": "--laps", "feedback": "--feedback", "rig": "--rig",
           "noise_px": "--noise-px", "noise_mm": "--noise-mm", "dropout": "--dropout",
           "strobe": "--strobe", "allow_unseen": "--allow-unseen", "seed": "--seed",
           "supersample": "--supersample", "full_frame": "--full-frame",
           "true_links_mm": "--true-links", "joint_offset_deg": "--joint-offset",
           "correction": "--correction", "preview": "--preview"}


def add_rule_options(ap: argparse.ArgumentParser, whose: str = "") -> None:
    """``--gain F``, ``--step S``, ``--tolerance W``: a rule base's f, S and w, ``whose``
    saying which rule bases take them; :func:`rule_params` reads and checks them."""
    ap.add_argument("--gain", type=float, metavar="F",
                    help="f of the variable step f*|error|, in deg per mm, for rules that use "
                         f"f{whose} (default {PARAM_DEFAULTS['f']})")
    ap.add_argument("--step", type=float, metavar="S",
                    help=f"fixed step S in deg, for rules that use S{whose} "
                         f"(default {PARAM_DEFAULTS['S']})")
    ap.add_argument("--tolerance", type=float, metavar="W",
                    help=f"tolerance w in mm, for rules that use w{whose} "
                         f"(default {PARAM_DEFAULTS['w']})")


def rule_params(args: argparse.Namespace) -> dict[str, float]:
    """The rule parameters given (:func:`add_rule_options`), by RunConfig field, checked as a
    run checks them (a `UserError` naming the option: ``--gain: must be in (0, 1e6] deg/mm``)."""
    given = {PARAM_FIELDS[name]: getattr(args, dest) for dest, name in RULE_OPTIONS.items()
             if getattr(args, dest) is not None}
    if given:
        from .errors import ConfigError
        from .runner import RunConfig

        try:
            RunConfig(**given).validate()
        except ConfigError as exc:
            raise exc.as_option(OPTIONS) from None
    return given


def labels(params: dict[str, float]) -> list[str]:
    """How ``run`` names given rule parameters in its default folder: ``f0.3``, ``S3``."""
    return [f"{PARAM_OF_FIELD[k]}{v:g}" for k, v in params.items()]
