"""Rule bases compiled to C: the step a microcontroller port would run, timed from Python.

:func:`c_function` writes a checked rule base (its parsed tree, never the file's text) as one C
function of doubles (:func:`c_source`: with the two small helpers it calls, a whole C99 file),
with the semantics of the module docstring of :mod:`itg_vision.rules`:

    static int itg_rules(const double *in, double *dq, int *fired, int *n_fired)

``in`` holds :meth:`RuleBase.arguments` in :attr:`RuleBase.argument_names` order; it returns 1
(and one fired rule) when an OUT_OF_REACH rule fires, else 0 with each joint's step in ``dq``
and the fired rules (their positions in the rule file; the Python wrapper hands back their
numbers) in ``fired``. It uses nothing but
``+ - * /``, comparisons, ``fabs`` and, for ``^`` other than a square, ``pow``: plain C99 for
any target.

:func:`build` compiles rule bases, with a CPython wrapper around each, into one extension
module with the machine's C compiler (``$CC``, else the one Python was built with) and returns
functions with the contract of :attr:`RuleBase.compiled`: the same arguments, the same
``(dq, fired)``, bit for bit the same steps (tested against the Python function and an
independent evaluator). Compiled with ``-ffp-contract=off`` (no fused multiply-add: every
operation rounds as Python's does), without fast-math, with ``-fno-builtin-pow`` (libm's pow
at run time, as Python calls it: GCC would otherwise turn ``x ^ -1`` into ``1 / x``, a power
that folds to 2 into a product and a constant to a constant power into its exact value, where
libm's pow may differ by an ulp), with ``-frounding-math`` (GCC 12 folds ``0 - fabs(x)`` into
``-fabs(x)``, -0 at x = 0 where Python gives +0, unless it may not assume the rounding mode)
and with ``-fno-math-errno``; ``itg_pow`` is declared a pure
function, so that the compiler computes a definition only on the paths that read it (the C
function computes every definition first, in file order). Modules are cached by the hash of
their source, the compiler (command, flags, version), the machine and its C library under
``$ITG_VISION_CACHE`` (default ``~/.cache/itg_vision``), written to a temporary name and
renamed; a cache that cannot be used (not a folder, not writable) is said on stderr, and the
module is built in a temporary folder for the process instead; a missing compiler is
:class:`NativeUnavailable`.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import platform
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from .errors import UserError
from .rules import Name, Node, Num, RuleBase, Unary, _is_square, _moves

#: Flags that keep C's arithmetic Python's: every operation rounded on its own.
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math", "-fno-math-errno",
          "-fno-builtin-pow", "-frounding-math")


class NativeUnavailable(UserError):
    """No C compiler, or the compiler refused the module (the message says which)."""


# --------------------------------------------------------------------------- C source
_C_OPS = {"and": "&&", "or": "||"}  # the others are C's own


def _c(node: Node) -> str:
    """C expression of a checked tree, fully parenthesised (a double, or an int for a
    condition)."""
    if isinstance(node, Num):
        return node.value.hex()  # exact: the same double as the file's number
    if isinstance(node, Name):
        return f"v_{node.name}"
    if isinstance(node, Unary):
        arg = _c(node.arg)
        return {"-": f"(-{arg})", "abs": f"fabs({arg})", "not": f"(!{arg})"}[node.op]
    left = _c(node.left)
    if _is_square(node):  # a square is the product, as in Python
        return f"itg_square({left})"
    if node.op == "^":
        return f"itg_pow({left}, {_c(node.right)})"
    return f"({left} {_C_OPS.get(node.op, node.op)} {_c(node.right)})"


_PRELUDE = """\
#include <math.h>

/* a ^ b as the rules define it (Python's float power, total): 0 ^ -b is +inf whatever the
   zero's sign; otherwise C99's pow (an overflow +-inf, a negative base to a fractional power
   NaN). A pure function (GCC, clang: declared so, and kept a call), so that a definition is
   computed only on the paths that read it. */
#if defined(__GNUC__)
__attribute__((const, noinline))
#endif
static double itg_pow(double a, double b) {
    if (a == 0.0 && b < 0.0) return INFINITY;
    return pow(a, b);
}

static inline double itg_square(double a) { return a * a; }
"""


def c_source(rb: RuleBase, name: str = "itg_rules") -> str:
    """The rule base as a C99 translation unit: :func:`c_function` after the two helpers it
    calls (``itg_square``, ``itg_pow``) and ``<math.h>``; what a port copies."""
    return _PRELUDE + "\n" + c_function(rb, name)


def c_function(rb: RuleBase, name: str = "itg_rules") -> str:
    """The C function of one rule base (see the module docstring): definitions in file order,
    OUT_OF_REACH rules, then each rule in file order firing when its condition holds and none
    of its joints is set yet."""
    n = rb.n_joints
    L = [f"static int {name}(const double *in, double *dq, int *fired, int *n_fired) {{"]
    L += [f"    const double v_{a} = in[{k}];" for k, a in enumerate(rb.argument_names)]
    L += [f"    const double v_{d.name} = {_c(d.expr)};" for d in rb.definitions]
    for k, r in enumerate(rb.rules):  # k: the rule's position in the file
        if r.out_of_reach:
            L += [f"    if ({_c(r.condition)}) {{ fired[0] = {k}; *n_fired = 1; return 1; }}"]
    L += [f"    int set[{n}] = {{0}};", "    int n = 0, k = 0;"]
    L += [f"    dq[{j}] = 0.0;" for j in range(n)]
    for k, r in enumerate(rb.rules):
        if r.out_of_reach:
            continue
        joints = sorted(r.joints)
        free = " && ".join(f"!set[{j - 1}]" for j in joints)
        L.append(f"    if ({free} && {_c(r.condition)}) {{")
        for j, a in _moves(r).items():
            L.append(f"        dq[{j - 1}] = {'-' if a.kind == 'dec' else ''}({_c(a.step)});")
        L += [f"        set[{j - 1}] = 1;" for j in joints]
        L += [f"        fired[k++] = {k}; n += {len(joints)};",
              f"        if (n == {n}) goto done;", "    }"]
    L += ["done:", "    *n_fired = k;", "    return 0;", "}"]
    return "\n".join(L) + "\n"


def _wrapper(rb: RuleBase, k: int) -> str:
    """CPython's face of function ``k``: ``METH_FASTCALL``, floats in, ``(dq, fired)`` out."""
    n_in, n_rules = len(rb.argument_names), len(rb.rules)
    return f"""
static PyObject *numbers_{k}[{n_rules}];

static PyObject *step_{k}(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {{
    double in[{n_in}], dq[{rb.n_joints}];
    int fired[{n_rules}], n_fired = 0;
    if (nargs != {n_in}) {{
        PyErr_Format(PyExc_TypeError, "rule step takes {n_in} arguments (%zd given)", nargs);
        return NULL;
    }}
    for (int i = 0; i < {n_in}; i++) {{  /* a float read directly; anything else converted */
        in[i] = PyFloat_CheckExact(args[i]) ? PyFloat_AS_DOUBLE(args[i]) : PyFloat_AsDouble(args[i]);
        if (in[i] == -1.0 && PyErr_Occurred()) return NULL;
    }}
    int out = rules_{k}(in, dq, fired, &n_fired);
    return itg_result(out, dq, {rb.n_joints}, fired, n_fired, numbers_{k});
}}
"""


_RESULT = """
/* (None, (number,)) when an OUT_OF_REACH rule fired, else ([dq...], [numbers...]): what the
   Python function returns. */
static PyObject *itg_result(int out, const double *dq, int n, const int *fired, int n_fired,
                            PyObject **numbers) {
    if (out) {
        PyObject *num = numbers[fired[0]];
        Py_INCREF(num);
        PyObject *t = PyTuple_New(1);
        if (t == NULL) { Py_DECREF(num); return NULL; }
        PyTuple_SET_ITEM(t, 0, num);
        PyObject *r = PyTuple_Pack(2, Py_None, t);
        Py_DECREF(t);
        return r;
    }
    PyObject *steps = PyList_New(n), *rules = NULL, *r = NULL;
    if (steps == NULL) return NULL;
    for (int j = 0; j < n; j++) {
        PyObject *v = PyFloat_FromDouble(dq[j]);
        if (v == NULL) goto fail;
        PyList_SET_ITEM(steps, j, v);
    }
    rules = PyList_New(n_fired);
    if (rules == NULL) goto fail;
    for (int i = 0; i < n_fired; i++) {
        Py_INCREF(numbers[fired[i]]);
        PyList_SET_ITEM(rules, i, numbers[fired[i]]);
    }
    r = PyTuple_Pack(2, steps, rules);
fail:
    Py_DECREF(steps);
    Py_XDECREF(rules);
    return r;
}
"""


def module_source(rule_bases, module: str) -> str:
    """One extension module: the C function of each rule base (``rules_<k>``) and its
    wrapper (``step_<k>``), then the module's table and init."""
    return _module_body(rule_bases) + _module_init(rule_bases, module)


def _module_body(rule_bases) -> str:
    parts = ["#define PY_SSIZE_T_CLEAN", "#include <Python.h>", _PRELUDE, _RESULT]
    for k, rb in enumerate(rule_bases):
        parts.append(f"/* rule base {k} */")  # (never the file's name: it is not C)
        parts.append(c_function(rb, f"rules_{k}"))
        parts.append(_wrapper(rb, k))
    return "\n".join(parts) + "\n"


def _module_init(rule_bases, module: str) -> str:
    table = "".join(f'    {{"step_{k}", (PyCFunction)(void (*)(void))step_{k}, METH_FASTCALL, NULL}},\n'
                    for k in range(len(rule_bases)))
    numbers = "".join(
        f'    if ((numbers_{k}[{i}] = PyLong_FromString("{r.number}", NULL, 10)) == NULL) return NULL;\n'
        for k, rb in enumerate(rule_bases) for i, r in enumerate(rb.rules))
    return f"""
static PyMethodDef methods[] = {{
{table}    {{NULL, NULL, 0, NULL}}
}};

static struct PyModuleDef module_def = {{PyModuleDef_HEAD_INIT, "{module}", NULL, -1, methods}};

PyMODINIT_FUNC PyInit_{module}(void) {{
{numbers}    return PyModule_Create(&module_def);
}}
"""


# --------------------------------------------------------------------------- build
def compiler() -> list[str]:
    """The C compiler command: ``$CC``, else the one this Python was built with, else ``cc``."""
    cc = shlex.split(os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc")
    if not cc or shutil.which(cc[0]) is None:
        raise NativeUnavailable(f"no C compiler: {cc[0] if cc else '$CC'!r} not found "
                                "(install gcc or clang, or set CC)")
    return cc


def cache_dir() -> Path:
    root = os.environ.get("ITG_VISION_CACHE") or Path.home() / ".cache" / "itg_vision"
    return Path(root) / "native"


def _link_flags() -> list[str]:
    """What the platform needs to link an extension module (macOS: Python's symbols resolved
    when loaded)."""
    return ["-undefined", "dynamic_lookup"] if sys.platform == "darwin" else []


_loaded: dict[str, object] = {}


def build(rule_bases) -> list:
    """The rule bases compiled to C in one extension module: one function per rule base with
    the contract of :attr:`RuleBase.compiled`. Built once per source and compiler (cached);
    :class:`NativeUnavailable` when it cannot be."""
    rule_bases = list(rule_bases)
    cc = compiler()
    flags = [*CFLAGS, *_link_flags(), f"-I{sysconfig.get_paths()['include']}"]
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    body = _module_body(rule_bases)  # the module's source but its name, made once
    key = hashlib.sha256("\0".join([body + _module_init(rule_bases, "itg_native"), *cc, *flags,
                                    suffix, *_toolchain(tuple(cc))]).encode()).hexdigest()[:20]
    name = f"itg_native_{key}"
    if name not in _loaded:
        source = body + _module_init(rule_bases, name)
        try:
            module = _load(name, cache_dir() / f"{name}{suffix}", source, cc, flags)
        except (ImportError, OSError) as exc:  # the cache unusable: build for this process only
            where = _scratch_dir()
            print(f"note: the compiled-rules cache {cache_dir()} cannot be used "
                  f"({getattr(exc, 'strerror', None) or exc}); building in {where} for this run "
                  "(set ITG_VISION_CACHE to a writable folder to keep the build)", file=sys.stderr)
            try:
                module = _load(name, where / f"{name}{suffix}", source, cc, flags)
            except (ImportError, OSError) as exc2:
                raise NativeUnavailable(f"{where}: {type(exc2).__name__}: {exc2}") from None
        _loaded[name] = module
    return [getattr(_loaded[name], f"step_{k}") for k in range(len(rule_bases))]


def _load(name: str, path: Path, source: str, cc: list[str], flags: list[str]):
    """The extension module ``name`` at ``path``, compiled there first if it is not yet."""
    if not path.exists():
        _compile(source, cc, flags, path)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.lru_cache(maxsize=None)
def _scratch_dir() -> Path:
    """A folder of this process's own for builds when the cache cannot be used; removed when
    the process ends."""
    import atexit
    import shutil

    where = Path(tempfile.mkdtemp(prefix="itg_vision-native-"))
    atexit.register(shutil.rmtree, where, ignore_errors=True)
    return where


def compiler_version() -> str:
    """The C compiler's version line ("" if it does not say); raises
    :class:`NativeUnavailable` without a compiler."""
    return _toolchain(tuple(compiler()))[0]


@functools.lru_cache(maxsize=None)
def _toolchain(cc: tuple) -> tuple[str, ...]:
    """What else decides the module's bytes: the compiler's version line, the machine and its
    C library (a cache shared by machines, or a compiler upgraded, builds anew)."""
    try:
        version = subprocess.run([*cc, "--version"], capture_output=True, text=True,
                                 timeout=60).stdout.partition("\n")[0]
    except (OSError, subprocess.TimeoutExpired):
        version = ""
    return version, platform.machine(), " ".join(platform.libc_ver())


def _compile(source: str, cc: list[str], flags: list[str], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".build-") as tmp:
        c_file, so_file = Path(tmp) / f"{path.stem}.c", Path(tmp) / path.name
        c_file.write_text(source)
        try:
            done = subprocess.run([*cc, *flags, str(c_file), "-o", str(so_file), "-lm"],
                                  capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise NativeUnavailable(f"C compiler {cc[0]!r} could not run: {exc}") from None
        if done.returncode != 0:
            first = next((ln for ln in done.stderr.splitlines() if "error" in ln),
                         done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "")
            raise NativeUnavailable(f"C compiler {' '.join(cc)} failed (exit {done.returncode}): "
                                    f"{first.strip()}")
        os.replace(so_file, path)  # whole, or not at all


def native_step(rb: RuleBase):
    """One rule base compiled to C (see :func:`build`)."""
    return build([rb])[0]
