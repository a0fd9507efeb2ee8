"""The ITG rule language: tokenizer, parser, compiler and :class:`RuleBase`.

A rule file reads like the paper's tables::

    # comment to end of line
    RULE 0: IF rd2 > (L1 + L2)^2 OR rd2 < (L1 - L2)^2 THEN OUT_OF_REACH
    RULE 1: IF (xd > xg AND yd > 0) OR (xd < xg AND yd < 0) THEN q1 -= f * |xd - xg|
    RULE 2: IF |xd - xg| <= w AND |yd - yg| <= w THEN q1 HOLD

A rule may span lines; each starts with ``RULE <n>:``. ``LET name = expr`` names a quantity
(a lever, a cross product) for the rules and definitions below it::

    LET C = xg * ye - yg * xe        # twice the area of the base-elbow-gripper triangle
    RULE 5: IF C * C > w * w * re2 THEN q2 += 57.29578 * (xg * (xd - xg) + yg * (yd - yg)) / C

Conditions combine comparisons
(``< <= > >= == !=``) with ``AND``, ``OR``, ``NOT`` and parentheses; expressions use numbers,
names, ``+ - * / ^``, ``|expr|`` and parentheses. Actions: ``qN += expr``, ``qN -= expr``,
``qN HOLD`` (also written ``qN = qN``), ``OUT_OF_REACH``; several separated by commas.

Semantics (the paper leaves these open; we choose):

- Rules whose action is ``OUT_OF_REACH`` (the paper's RULE 0) are checked first; if one fires
  the set point is out of reach and no joint moves.
- The others are scanned in file order. A rule fires when its condition holds and none of its
  joints has been set by an earlier rule in this scan: each joint changes at most once per
  iteration ("only one rule will be matched at each time", per joint).
- Comparisons with NaN (a marker the arm lacks) are false.
- Definitions are computed once per iteration, in file order, before any rule is tested; a
  name is known from its ``LET`` on and cannot be defined twice or shadow a built-in name.

Names: desired ``xd yd zd``, gripper ``xg yg zg``, elbow ``xe ye ze`` (mm); radial squares
``rd2 rg2 re2`` (x^2 + y^2, mm^2); joints ``q1..qn`` (deg); gain ``f`` (deg/mm), fixed step
``S`` (deg), tolerance ``w`` (mm); link lengths ``L1..Ln`` and ``L`` (= L1) in mm.

The file text is never evaluated: the parsed tree is checked (names, joints) and compiled into
one Python function from the tree itself.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError

MARKER_NAMES = ("xd", "yd", "zd", "xg", "yg", "zg", "xe", "ye", "ze", "rd2", "rg2", "re2")
PARAM_NAMES = ("f", "S", "w")
KEYWORDS = {"RULE", "IF", "THEN", "AND", "OR", "NOT", "HOLD", "OUT_OF_REACH", "LET"}

_TOKEN = re.compile(r"""
    (?P<ws>[ \t\r]+) | (?P<nl>\n) | (?P<comment>\#[^\n]*)
  | (?P<num>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z_0-9]*)
  | (?P<op>\+=|-=|<=|>=|==|!=|[-+*/^()|<>:,=])
  | (?P<bad>.)
""", re.VERBOSE)


@dataclass(frozen=True)
class Token:
    kind: str  # num, name, kw, op, end
    text: str
    line: int
    col: int


class RuleSyntaxError(UserError):
    pass


def tokenize(text: str, source: str = "<rules>") -> list[Token]:
    tokens, line, line_start = [], 1, 0
    for m in _TOKEN.finditer(text):
        kind, s = m.lastgroup, m.group()
        col = m.start() - line_start + 1
        if kind == "nl":
            line, line_start = line + 1, m.end()
        elif kind in ("ws", "comment"):
            continue
        elif kind == "bad":
            raise RuleSyntaxError(f"{source}:{line}:{col}: unexpected character {s!r}")
        elif kind == "name" and s.upper() in KEYWORDS:
            tokens.append(Token("kw", s.upper(), line, col))
        else:
            tokens.append(Token(kind, s, line, col))
    tokens.append(Token("end", "", line, max(1, len(text) - line_start + 1)))
    return tokens


# --------------------------------------------------------------------------- syntax tree
# Expressions and conditions are tuples: ("num", v) ("name", n, tok) ("neg", e) ("abs", e)
# ("bin", op, a, b) ("cmp", op, a, b) ("and", a, b) ("or", a, b) ("not", a)


@dataclass(frozen=True)
class Action:
    kind: str  # "inc", "dec", "hold", "out"
    joint: int = 0  # 1-based
    step: tuple | None = None


@dataclass(frozen=True)
class Rule:
    number: int
    condition: tuple
    actions: tuple[Action, ...]
    line: int
    text: str = ""

    @property
    def out_of_reach(self) -> bool:
        return any(a.kind == "out" for a in self.actions)


@dataclass(frozen=True)
class Definition:
    """``LET name = expr``: a named quantity, computed before the rules at each iteration."""

    name: str
    expr: tuple
    line: int
    col: int


class _Parser:
    def __init__(self, tokens: list[Token], source: str):
        self.t, self.i, self.source = tokens, 0, source
        self.definitions: list[Definition] = []

    # helpers
    @property
    def tok(self) -> Token:
        return self.t[self.i]

    def error(self, msg: str, tok: Token | None = None) -> RuleSyntaxError:
        tok = tok or self.tok
        found = "end of file" if tok.kind == "end" else repr(tok.text)
        return RuleSyntaxError(f"{self.source}:{tok.line}:{tok.col}: {msg} (found {found})")

    def accept(self, kind: str, text: str | None = None) -> Token | None:
        tok = self.tok
        if tok.kind == kind and (text is None or tok.text == text):
            self.i += 1
            return tok
        return None

    def expect(self, kind: str, text: str | None = None, what: str = "") -> Token:
        tok = self.accept(kind, text)
        if tok is None:
            raise self.error(f"expected {what or text or kind}")
        return tok

    # grammar
    def rules(self) -> list[Rule]:
        out = []
        while self.tok.kind != "end":
            if self.tok.kind == "kw" and self.tok.text == "LET":
                self.definitions.append(self.definition())
            else:
                out.append(self.rule())
        return out

    def _at_statement_end(self) -> bool:
        return self.tok.kind == "end" or (self.tok.kind == "kw" and self.tok.text in ("RULE", "LET"))

    def definition(self) -> Definition:
        self.expect("kw", "LET")
        name = self.expect("name", what="a name after LET")
        self.expect("op", "=", f"'=' after LET {name.text}")
        expr = self.expr()
        if not self._at_statement_end():
            raise self.error("expected the next 'RULE' or 'LET'")
        return Definition(name.text, expr, name.line, name.col)

    def rule(self) -> Rule:
        start = self.expect("kw", "RULE", "'RULE <n>:'")
        num = self.expect("num", what="a rule number")
        if not re.fullmatch(r"\d+", num.text):
            raise self.error("rule number must be a whole number", num)
        self.expect("op", ":", "':' after the rule number")
        self.expect("kw", "IF", "'IF'")
        cond = self.condition()
        self.expect("kw", "THEN", "'THEN' or a logical operator")
        actions = [self.action()]
        while self.accept("op", ","):
            actions.append(self.action())
        if not self._at_statement_end():
            raise self.error("expected ',' or the next 'RULE'")
        return Rule(int(num.text), cond, tuple(actions), start.line)

    def action(self) -> Action:
        if self.accept("kw", "OUT_OF_REACH"):
            return Action("out")
        tok = self.tok
        if tok.kind != "name" or not re.fullmatch(r"q[1-9]", tok.text):
            raise self.error("expected an action: qN += step, qN -= step, qN HOLD or OUT_OF_REACH")
        self.i += 1
        joint = int(tok.text[1:])
        if self.accept("kw", "HOLD"):
            return Action("hold", joint)
        if self.accept("op", "="):
            same = self.expect("name", what=f"{tok.text} (as in '{tok.text} = {tok.text}')")
            if same.text != tok.text:
                raise self.error(f"only '{tok.text} = {tok.text}' (hold) is allowed", same)
            return Action("hold", joint)
        op = self.accept("op", "+=") or self.accept("op", "-=")
        if op is None:
            raise self.error(f"expected '+=', '-=', '=' or HOLD after {tok.text}")
        return Action("inc" if op.text == "+=" else "dec", joint, self.expr())

    def condition(self):
        node = self.conjunction()
        while self.accept("kw", "OR"):
            node = ("or", node, self.conjunction())
        return node

    def conjunction(self):
        node = self.negation()
        while self.accept("kw", "AND"):
            node = ("and", node, self.negation())
        return node

    def negation(self):
        if self.accept("kw", "NOT"):
            return ("not", self.negation())
        if self.tok.kind == "op" and self.tok.text == "(":
            # '(' opens either a condition or an expression: try the condition first.
            save = self.i
            self.i += 1
            try:
                node = self.condition()
                if self.accept("op", ")") and not self._at_expression_operator():
                    return node
            except RuleSyntaxError:
                pass
            self.i = save
        return self.comparison()

    def _at_expression_operator(self) -> bool:
        return self.tok.kind == "op" and self.tok.text in {"+", "-", "*", "/", "^", "<", "<=", ">",
                                                            ">=", "==", "!="}

    def comparison(self):
        left = self.expr()
        tok = self.tok
        if tok.kind == "op" and tok.text in ("<", "<=", ">", ">=", "==", "!="):
            self.i += 1
            return ("cmp", tok.text, left, self.expr())
        raise self.error("expected a comparison (<, <=, >, >=, ==, !=)")

    def expr(self):
        node = self.term()
        while self.tok.kind == "op" and self.tok.text in "+-" and len(self.tok.text) == 1:
            op = self.tok.text
            self.i += 1
            node = ("bin", op, node, self.term())
        return node

    def term(self):
        node = self.unary()
        while self.tok.kind == "op" and self.tok.text in ("*", "/"):
            op = self.tok.text
            self.i += 1
            node = ("bin", op, node, self.unary())
        return node

    def unary(self):
        if self.accept("op", "-"):
            return ("neg", self.unary())
        if self.accept("op", "+"):
            return self.unary()
        return self.power()

    def power(self):
        base = self.atom()
        if self.accept("op", "^"):
            return ("bin", "^", base, self.unary())
        return base

    def atom(self):
        tok = self.tok
        if tok.kind == "num":
            self.i += 1
            return ("num", float(tok.text))
        if tok.kind == "name":
            self.i += 1
            return ("name", tok.text, tok)
        if self.accept("op", "("):
            node = self.expr()
            self.expect("op", ")", "')'")
            return node
        if self.accept("op", "|"):
            node = self.expr()
            self.expect("op", "|", "closing '|'")
            return ("abs", node)
        raise self.error("expected a number, a name, '(' or '|'")


# --------------------------------------------------------------------------- compiler
_PY_OP = {"^": "**", "and": "and", "or": "or"}


def _names_in(node) -> list[tuple[str, Token]]:
    if node is None:
        return []
    if node[0] == "name":
        return [(node[1], node[2])]
    return [n for child in node[1:] if isinstance(child, tuple) for n in _names_in(child)]


def _py(node) -> str:
    kind = node[0]
    if kind == "num":
        return repr(node[1])
    if kind == "name":
        return f"v_{node[1]}"
    if kind == "neg":
        return f"(-{_py(node[1])})"
    if kind == "abs":
        return f"abs({_py(node[1])})"
    if kind == "not":
        return f"(not {_py(node[1])})"
    if kind in ("and", "or"):
        return f"({_py(node[1])} {kind} {_py(node[2])})"
    op = node[1]
    return f"({_py(node[2])} {_PY_OP.get(op, op)} {_py(node[3])})"


@dataclass(frozen=True)
class Step:
    """The ITG's decision at one iteration: joint increments (deg) and the rules that fired."""

    dq_deg: np.ndarray
    fired: tuple[int, ...]
    out_of_reach: bool = False


@dataclass
class RuleBase:
    """A compiled rule base for one arm.

    Parameters
    ----------
    rules : parsed rules.
    n_joints : joints the arm has (rules naming others are refused).
    links_mm : link lengths bound to ``L1..Ln`` and ``L``.
    f, S, w : gain (deg/mm), fixed step (deg), tolerance (mm).
    """

    rules: list[Rule]
    n_joints: int
    links_mm: tuple[float, ...]
    f: float = 0.06
    S: float = 0.5
    w: float = 0.5
    source: str = "<rules>"
    definitions: tuple[Definition, ...] = ()
    _fn: object = field(default=None, repr=False)

    @classmethod
    def from_text(cls, text: str, n_joints: int, links_mm, source: str = "<rules>", **params):
        parser = _Parser(tokenize(text, source), source)
        rules = parser.rules()
        lines = text.splitlines()
        rules = [Rule(r.number, r.condition, r.actions, r.line, lines[r.line - 1].strip())
                 for r in rules]
        rb = cls(rules, n_joints, tuple(float(v) for v in links_mm), source=source,
                 definitions=tuple(parser.definitions), **params)
        rb._check()
        rb._fn = rb._compile()
        return rb

    @classmethod
    def from_file(cls, path: str | Path, n_joints: int, links_mm, **params) -> "RuleBase":
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise UserError(f"{path}: cannot read rule file ({exc.strerror})") from None
        return cls.from_text(text, n_joints, links_mm, source=str(path), **params)

    # -------------------------------------------------------------- checks
    @property
    def known_names(self) -> set[str]:
        joints = {f"q{i}" for i in range(1, self.n_joints + 1)}
        links = {f"L{i}" for i in range(1, len(self.links_mm) + 1)} | {"L"}
        return set(MARKER_NAMES) | set(PARAM_NAMES) | joints | links

    def _check(self) -> None:
        if not self.rules:
            raise UserError(f"{self.source}: no rules found")
        known = self.known_names
        defined: dict[str, int] = {}  # LET name -> its line
        for d in self.definitions:
            self._check_names([d.expr], known | set(defined))
            if d.name in known or d.name in defined or re.fullmatch(r"q\d+|L\d+", d.name):
                first = f"LET on line {defined[d.name]}" if d.name in defined else "a built-in name"
                raise UserError(f"{self.source}:{d.line}:{d.col}: {d.name!r} is already {first}")
            defined[d.name] = d.line
        seen: dict[int, int] = {}
        for r in self.rules:
            if r.number in seen:
                raise UserError(f"{self.source}:{r.line}: RULE {r.number} is defined twice "
                                f"(first on line {seen[r.number]})")
            seen[r.number] = r.line
            above = {name for name, line in defined.items() if line < r.line}
            self._check_names([r.condition] + [a.step for a in r.actions], known | above)
            for a in r.actions:
                if a.kind != "out" and not 1 <= a.joint <= self.n_joints:
                    raise UserError(f"{self.source}:{r.line}: RULE {r.number} moves q{a.joint}, "
                                    f"but the arm has {self.n_joints} joint(s)")
            if r.out_of_reach and len(r.actions) > 1:
                raise UserError(f"{self.source}:{r.line}: OUT_OF_REACH must be a rule's only action")
        if not any(not r.out_of_reach for r in self.rules):
            raise UserError(f"{self.source}: no rule moves a joint")

    def _check_names(self, nodes, known: set[str]) -> None:
        for name, tok in (n for node in nodes for n in _names_in(node)):
            if name not in known:
                raise UserError(f"{self.source}:{tok.line}:{tok.col}: unknown name {name!r} "
                                f"(known: {', '.join(sorted(known))})")

    # -------------------------------------------------------------- compile
    def _compile(self):
        n = self.n_joints
        args = ", ".join(f"v_{m}" for m in MARKER_NAMES)
        qs = "".join(f"v_q{i}, " for i in range(1, n + 1))
        lines = [f"def _itg_step({args}, {qs}v_f, v_S, v_w, v_L, {', '.join(f'v_L{i}' for i in range(1, len(self.links_mm) + 1))}):"]
        for d in self.definitions:
            lines.append(f"    v_{d.name} = {_py(d.expr)}")
        for r in (r for r in self.rules if r.out_of_reach):
            lines.append(f"    if {_py(r.condition)}:")
            lines.append(f"        return None, ({r.number},)")
        lines.append(f"    dq = [0.0] * {n}")
        lines.append(f"    free = [True] * {n}")
        lines.append("    fired = []")
        for r in (r for r in self.rules if not r.out_of_reach):
            joints = sorted({a.joint - 1 for a in r.actions})
            guard = " and ".join(f"free[{j}]" for j in joints)
            lines.append(f"    if {guard} and {_py(r.condition)}:")
            for a in r.actions:
                j = a.joint - 1
                if a.kind != "hold":
                    sign = "" if a.kind == "inc" else "-"
                    lines.append(f"        dq[{j}] = {sign}({_py(a.step)})")
                lines.append(f"        free[{j}] = False")
            lines.append(f"        fired.append({r.number})")
        lines.append("    return dq, fired")
        namespace: dict = {}
        exec(compile("\n".join(lines), f"<compiled {self.source}>", "exec"), namespace)  # noqa: S102 - source generated from the checked tree
        return namespace["_itg_step"]

    # -------------------------------------------------------------- run
    @property
    def compiled(self):
        """The compiled rule function; it takes :meth:`arguments` and returns (dq, fired)."""
        return self._fn

    def arguments(self, desired_mm, markers, q_deg) -> tuple[float, ...]:
        """The compiled function's arguments, in its order, as plain Python floats (with NaN,
        comparisons are False and raise no warning)."""
        d, g, e = desired_mm, markers.gripper_mm, markers.elbow_mm
        xd, yd, zd = float(d[0]), float(d[1]), float(d[2])
        xg, yg, zg = float(g[0]), float(g[1]), float(g[2])
        xe, ye, ze = float(e[0]), float(e[1]), float(e[2])
        links = self.links_mm
        return (xd, yd, zd, xg, yg, zg, xe, ye, ze,
                xd * xd + yd * yd, xg * xg + yg * yg, xe * xe + ye * ye,
                *(float(q) for q in q_deg), self.f, self.S, self.w, links[0], *links)

    def step(self, desired_mm, markers, q_deg) -> Step:
        """Apply the rules once. ``markers`` has ``gripper_mm`` and ``elbow_mm`` (shape (3,))."""
        dq, fired = self._fn(*self.arguments(desired_mm, markers, q_deg))
        if dq is None:
            return Step(np.zeros(self.n_joints), tuple(fired), True)
        if any(v != v for v in dq):  # a NaN estimate must never move a joint
            dq = [0.0 if v != v else v for v in dq]
        return Step(np.array(dq), tuple(fired), False)


RULES_DIR = Path(__file__).resolve().parent.parent / "data" / "rules"
DEFAULT_RULES = {"one-link": "table1", "two-link": "table2", "three-link": "three-link"}


def resolve_rules_path(name_or_path: str) -> Path:
    """A shipped rule base by name (``table1``, ``table2``, ``three-link``) or a file path."""
    p = Path(name_or_path)
    if p.suffix == ".rules" or p.exists() or "/" in name_or_path:
        if not p.exists():
            raise UserError(f"{p}: rule file not found")
        return p
    candidate = RULES_DIR / f"{name_or_path}.rules"
    if not candidate.exists():
        shipped = sorted(q.stem for q in RULES_DIR.glob("*.rules"))
        raise UserError(f"unknown rule base {name_or_path!r} (shipped: {', '.join(shipped)}; "
                        "or give a path to a .rules file)")
    return candidate


def load_rules(name_or_path: str, n_joints: int, links_mm, **params) -> RuleBase:
    return RuleBase.from_file(resolve_rules_path(name_or_path), n_joints, links_mm, **params)


