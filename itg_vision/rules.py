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
``qN HOLD`` (also written ``qN = qN``), ``OUT_OF_REACH``; several separated by commas, one per
joint.

Semantics (the paper leaves these open; we choose):

- Rules whose action is ``OUT_OF_REACH`` (the paper's RULE 0) are checked first; if one fires
  the set point is out of reach and no joint moves.
- The others are scanned in file order. A rule fires when its condition holds and none of its
  joints has been set by an earlier rule in this scan: each joint changes at most once per
  iteration ("only one rule will be matched at each time", per joint), and a rule that sets
  every joint ends the scan.
- Comparisons with NaN (a marker the arm lacks) are false (``!=`` is true, as in IEEE 754).
- A definition is a pure quantity, computed when first needed: before the first condition or
  step that reads it (the same values as computing them all first, in file order). A name is
  known from its ``LET`` on and cannot be defined twice or shadow a built-in name.

Arithmetic is total and checked (the paper says nothing; we choose IEEE 754 doubles):

- Numbers in the file must be finite doubles (``1e999`` or a 400-digit number is refused at
  its line and column).
- Every operation yields a number: ``x / 0`` is +-inf (``0 / 0`` NaN), ``0 ^ -1`` is inf, an
  overflow is +-inf, a negative number to a fractional power (a complex number) is NaN. In a
  condition such a value simply compares (NaN compares false).
- A step (the value added to a joint) that is not a finite number, computed from finite
  inputs, stops the run: :meth:`RuleBase.step` raises :class:`~itg_vision.errors.UserError`
  naming the rule, the joint, the step and the values it was computed from. A step computed
  from a NaN input (a marker the arm lacks or never measured) moves nothing, as before.

Limits (stated, so nothing ends in a RecursionError or MemoryError): a rule file is at most
:data:`~itg_vision.inputs.MAX_FILE_BYTES` of UTF-8 text; a rule at most :data:`MAX_RULE_TOKENS`
tokens; conditions and expressions at most :data:`MAX_DEPTH` levels deep (each parenthesis,
``|...|``, ``NOT``, sign, operator and each further operand of a chain ``a + b + c`` adds a
level). Beyond them the file is refused at the line and column where the limit is crossed.
A rule base loaded for an arm (:func:`load_rules`) must move every joint of it: ``table1``
(one joint) on the two-link arm is refused rather than run with q2 frozen.

A line ``#! S is the servo limit`` (a comment to the parser) declares that the rules' S is the
loop's servo limit: :attr:`RuleBase.servo_step` is then true, and the runner binds S to the
run's ``max_step_deg`` rather than to ``--step`` (the ITG+ rule bases, whose steps are clipped
to +-S and whose compensations assume each joint moves what the rules ask).

Names: desired ``xd yd zd``, gripper ``xg yg zg``, elbow ``xe ye ze`` (mm; none on a one-link arm); radial squares
``rd2 rg2 re2`` (x^2 + y^2, mm^2); the pitch axis ``xa ya`` (three-link only: the loop's kept
axis, :attr:`~itg_vision.contracts.Markers.pitch_axis`, a horizontal unit vector; NaN where no
loop keeps one); joints ``q1..qn`` (deg); gain ``f`` (deg/mm), fixed step
``S`` (deg), tolerance ``w`` (mm); link lengths ``L1..Ln`` and ``L`` (= L1) in mm, and ``sL`` (mm),
the largest standard error of the lengths: 0 for the nominal model's, else what the noise of the
start-up's looks leaves uncertain in the measured ones (a reach test on measured lengths allows a
few: RULE 0 of ``itg-plus-two-link``), and ``h`` (mm), the LEDs' stand-off from the links along
the pitch axis (three-link, measured at start-up like the lengths; 0 on planar arms, whose LEDs
stand along z: RULE 0 of ``itg-plus-three-link``, the LED's reach).

The file text is never evaluated: the parsed tree is checked (names, joints) and compiled into
one Python function from the tree itself.
"""

from __future__ import annotations

import bisect
import itertools
import math
import re
from collections import ChainMap, Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .contracts import Step
from .errors import UserError
from .inputs import clip, is_real, is_whole, read_text
from .shipped import RULES_DIR, names_a_path, not_found, or_a_path, rule_names

MARKER_NAMES = ("xd", "yd", "zd", "xg", "yg", "zg", "xe", "ye", "ze", "rd2", "rg2", "re2", "xa",
                "ya")
ELBOW_NAMES = ("xe", "ye", "ze", "re2")  # none on a one-link arm
AXIS_NAMES = ("xa", "ya")  # the three-link arm's pitch axis, as the loop keeps it
#: The rule parameters and the field names (units included) they go by outside the rules.
PARAM_FIELDS = {"f": "gain_deg_per_mm", "S": "step_deg", "w": "tolerance_mm"}
#: The other way: RunConfig field -> the rules' name.
PARAM_OF_FIELD = {field_: name for name, field_ in PARAM_FIELDS.items()}
#: Each parameter's unit, as a user reads it.
PARAM_UNITS = {"f": "deg/mm", "S": "deg", "w": "mm"}
#: Their defaults (deg/mm, deg, mm), the same from code, from ``run`` and from ``paper``: the
#: paper's gain read in deg/mm, a 2 deg fixed step, a 0.5 mm tolerance.
PARAM_DEFAULTS = {"f": 0.5, "S": 2.0, "w": 0.5}
PARAM_NAMES = ("f", "S", "w")
#: The declaration that a rule base's S is the loop's servo limit (a line of its own).
SERVO_STEP = re.compile(r"[ \t]*#![ \t]*S is the servo limit[ \t\r]*")  # indented too
KEYWORDS = {"RULE", "IF", "THEN", "AND", "OR", "NOT", "HOLD", "OUT_OF_REACH", "LET"}
#: The comparison operators (which do not chain: 'a < b < c' is refused).
COMPARISONS = ("<", "<=", ">", ">=", "==", "!=")
#: The hint of a chained comparison, 'a < b < c' or '(a < b) < c'.
_NO_CHAIN = ": comparisons do not chain; write 'a < b AND b < c'"
#: The operators that may follow an operand in an expression or a comparison.
_OPERAND_FOLLOWERS = frozenset({"+", "-", "*", "/", "^", *COMPARISONS})
#: A joint's name, q1..q9: what an action sets.
JOINT_NAME = re.compile(r"q[1-9]")
#: Deepest condition or expression accepted (levels of nesting and of operators).
MAX_DEPTH = 50
#: Longest rule accepted (tokens: numbers, names, operators, keywords).
MAX_RULE_TOKENS = 1000
#: Longest if/elif chain in the compiled function (then a new ``if`` and flags).
MAX_ELIF = 100

_TOKEN = re.compile(r"""
    (?P<ws>[ \t\r]+) | (?P<nl>\n) | (?P<comment>\#[^\n]*)
  | (?P<num>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z_0-9]*)
  | (?P<op>\+=|-=|<=|>=|==|!=|[-+*/^()|<>:,=])
  | (?P<bad>.)
""", re.VERBOSE | re.ASCII)  # ASCII digits, as trajectory files


#: What a name qN or LN stands for, whether or not the arm has joint or link N.
_RESERVED = {"q": "joint N's angle", "L": "link N's length"}
#: A number run into letters, digits, '_' or a '.' ('1_000', '0x10', '1e', '5mm', '1.5.2').
_GLUED = re.compile(r"[A-Za-z_0-9.]")
_GLUED_WORD = re.compile(r"[A-Za-z_0-9.]+")


@dataclass(frozen=True)
class Token:
    kind: str  # num, name, kw, op, end
    text: str
    line: int
    col: int


class RuleSyntaxError(UserError):
    pass


class RuleLimitError(RuleSyntaxError):
    """A stated limit crossed: never retried by the parser's backtracking."""


class ForAnotherArm(UserError):
    """A rule base that names a joint, a link or the elbow the arm lacks; ``joints``: the
    fewest joints an arm needs for every name of it (:func:`load_rules` says when that is more
    than the arm's: a rule base for another arm)."""

    def __init__(self, message: str, joints: int):
        super().__init__(message)
        self.joints = joints


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
            hint = ": '&&' is not an operator here, AND is" if s == "&" else ""
            raise RuleSyntaxError(f"{source}:{line}:{col}: unexpected character {s!r}{hint}")
        elif kind == "num" and _GLUED.match(text, m.end()):
            word = _GLUED_WORD.match(text, m.start()).group()
            raise RuleSyntaxError(f"{source}:{line}:{col}: {clip(word)!r} is not a number: write "
                                  "digits, an optional '.' and exponent (1000, 0.5, 2.5e-3), and a "
                                  "product with its * (2 * S)")
        elif kind == "num" and not math.isfinite(float(s)):
            raise RuleSyntaxError(f"{source}:{line}:{col}: number {clip(s)} is out of range "
                                  "(the largest is about 1.8e308)")
        elif kind == "name" and s.upper() in KEYWORDS:
            tokens.append(Token("kw", s.upper(), line, col))
        else:
            tokens.append(Token(kind, s, line, col))
    tokens.append(Token("end", "", line, max(1, len(text) - line_start + 1)))
    return tokens


# --------------------------------------------------------------------------- syntax tree
@dataclass(frozen=True)
class Num:
    """A number (finite: checked by the tokenizer)."""

    value: float


@dataclass(frozen=True)
class Name:
    """A name: a marker coordinate, a joint, a parameter, a link length or a LET definition."""

    name: str
    tok: Token


@dataclass(frozen=True)
class Unary:
    """``-x``, ``|x|`` (op "abs") or ``NOT c``."""

    op: str
    arg: "Node"


@dataclass(frozen=True)
class Binary:
    """Arithmetic (+ - * / ^), a comparison (< <= > >= == !=) or a logical AND / OR."""

    op: str
    left: "Node"
    right: "Node"


Node = Num | Name | Unary | Binary


def children(node: Node) -> tuple:
    if isinstance(node, Unary):
        return (node.arg,)
    if isinstance(node, Binary):
        return (node.left, node.right)
    return ()


@dataclass(frozen=True)
class Action:
    kind: str  # "inc", "dec", "hold", "out"
    joint: int = 0  # 1-based
    step: Node | None = None
    where: tuple[int, int] = field(default=(0, 0), compare=False)  # (line, col) in the file


@dataclass(frozen=True)
class Rule:
    number: int
    condition: Node
    actions: tuple[Action, ...]
    line: int
    text: str = ""
    col: int = field(default=0, compare=False)  # of 'RULE'
    end: tuple[int, int] = field(default=(0, 0), compare=False)  # (line, col) just past its last token

    @property
    def out_of_reach(self) -> bool:
        return any(a.kind == "out" for a in self.actions)

    @property
    def joints(self) -> set[int]:
        """The joints it sets (moves or holds), 1-based."""
        return {a.joint for a in self.actions if a.kind != "out"}


@dataclass(frozen=True)
class Definition:
    """``LET name = expr``: a named quantity, computed where a rule first needs it."""

    name: str
    expr: Node
    line: int
    col: int


class _Parser:
    def __init__(self, tokens: list[Token], source: str):
        self.t, self.i, self.source = tokens, 0, source
        self._index = {id(t): k for k, t in enumerate(tokens)}  # a token's place, for _slip
        self.nesting = 0  # recursion: parentheses, |...|, NOT, signs, powers
        self._height: dict[int, int] = {}  # id(node) -> height of its subtree
        self.definitions: list[Definition] = []

    def _too_deep(self, tok: Token) -> RuleLimitError:
        return RuleLimitError(
            f"{self.at(tok)}: nested too deeply: more than {MAX_DEPTH} levels "
            "(each parenthesis, |...|, NOT, sign, operator and each further operand of a chain "
            "like a + b + c adds one)")

    def node(self, tok: Token, node: Node) -> Node:
        """A syntax-tree node; refused when its subtree is more than MAX_DEPTH levels high."""
        h = 1 + max((self._height.get(id(c), 1) for c in children(node)), default=0)
        if h > MAX_DEPTH:
            raise self._too_deep(tok)
        self._height[id(node)] = h
        return node

    def enter(self, tok: Token) -> None:
        self.nesting += 1
        if self.nesting > MAX_DEPTH:
            raise self._too_deep(tok)

    # helpers
    @property
    def tok(self) -> Token:
        return self.t[self.i]

    def at(self, tok: Token) -> str:
        """Where a token is, as messages name it: ``file:line:col``."""
        return f"{self.source}:{tok.line}:{tok.col}"

    def error(self, msg: str, tok: Token | None = None) -> RuleSyntaxError:
        tok = tok or self.tok
        found = "end of file" if tok.kind == "end" else repr(clip(tok.text))
        return RuleSyntaxError(f"{self.at(tok)}: {msg} (found {found}){self._slip(tok)}")

    def _slip(self, tok: Token) -> str:
        """The likely slip behind an error at ``tok``, as a hint ('' if none is clear): two
        operands side by side (a product written without its *), two actions without the
        ',' between them, '=>', '=<' or a single '=' where a comparison belongs, C's '||'
        and Python's '**', or a chained comparison ('a < b < c')."""
        k = self._index.get(id(tok), -1)  # an error made while backtracking costs O(1) here
        before = self.t[k - 1] if k > 0 else None
        after = self.t[k + 1] if 0 <= k < len(self.t) - 1 else None
        if tok.text == "=" and after is not None and after.text in ("<", ">") \
                and after.col == tok.col + 1 and after.line == tok.line:
            return f": '={after.text}' is not an operator, '{after.text}=' is"
        if tok.text == "=" and before is not None and before.kind in ("num", "name") \
                and not JOINT_NAME.fullmatch(before.text):
            return ": '=' is not a comparison, '==' is"
        if JOINT_NAME.fullmatch(tok.text) and after is not None \
                and after.text in ("+=", "-=", "=", "HOLD") and (before is None or before.text != ","):
            opened = next((self.t[j].text for j in range(k - 1, -1, -1) if self.t[j].kind == "kw"
                           and self.t[j].text in ("THEN", "RULE")), None)  # in the actions?
            return (": the next action needs a ',' before it" if opened == "THEN" else
                    ": is 'THEN' missing before the actions?")
        for a, b in ((before, tok), (tok, after)):  # '||' or '**' written as in C or Python
            if a is not None and b is not None and a.text == b.text and a.text in ("|", "*") \
                    and (b.line, b.col) == (a.line, a.col + 1):
                return f": '{a.text * 2}' is not an operator here, {'OR' if a.text == '|' else '^'} is"
        if tok.text in COMPARISONS and self._after_comparison(k):
            return _NO_CHAIN
        named = k > 1 and self.t[k - 2].kind == "kw" and self.t[k - 2].text in ("LET", "RULE")
        operand_end = before is not None and not named and (before.kind in ("num", "name")
                                                             or before.text == ")")
        if operand_end and (tok.kind in ("num", "name") or tok.text in ("(", "|")):
            return f": two operands side by side; a product needs its * ('{before.text} * ...')"
        return ""

    def _after_comparison(self, k: int) -> bool:
        """Whether token ``k`` follows a comparison's operands, ``a < b`` of ``a < b < c``:
        a comparison operator before it in its parentheses, with no keyword or ',' between (a
        rule's 'IF' at the farthest: the look back is as long as the rule at most)."""
        depth = 0
        for t in (self.t[j] for j in range(k - 1, -1, -1)):
            depth += (t.text == ")") - (t.text == "(")
            if depth < 0 or t.kind == "kw" or (t.text == "," and depth == 0):
                return False
            if depth == 0 and t.kind == "op" and t.text in COMPARISONS:
                return True
        return False

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

    def close(self, opener: Token) -> Token:
        """The token closing ``opener`` ('(' or '|'); its error says where ``opener`` stands."""
        closing, what = (")", "')'") if opener.text == "(" else ("|", "closing '|'")
        return self.expect("op", closing, f"{what} (opened at line {opener.line}, column {opener.col})")

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
        end = self.i
        while self.t[end].kind != "end" and not (self.t[end].kind == "kw" and self.t[end].text in ("RULE", "LET")):
            end += 1
            if end - self.i >= MAX_RULE_TOKENS:
                tok = self.t[end]
                raise RuleLimitError(f"{self.at(tok)}: RULE is longer than "
                                     f"{MAX_RULE_TOKENS} tokens (it starts on line {start.line})")
        num = self.expect("num", what="a rule number")
        if not re.fullmatch(r"\d+", num.text):
            raise self.error("rule number must be a whole number", num)
        self.expect("op", ":", "':' after the rule number")
        self.expect("kw", "IF", "'IF'")
        cond = self.condition()
        self.expect("kw", "THEN", "'THEN' or a logical operator")
        actions = [self.action()]
        while self.accept("op", ","):
            tok = self.tok
            actions.append(self.action())
            joint = actions[-1].joint
            if actions[-1].kind != "out" and any(a.joint == joint for a in actions[:-1]):
                raise self.error(f"q{joint} has two actions in one rule", tok)
        if not self._at_statement_end():
            raise self.error("expected ',' or the next 'RULE'")
        last = self.t[self.i - 1]
        return Rule(int(num.text), cond, tuple(actions), start.line, col=start.col,
                    end=(last.line, last.col + len(last.text)))

    def action(self) -> Action:
        tok = self.tok
        if self.accept("kw", "OUT_OF_REACH"):
            return Action("out", where=(tok.line, tok.col))
        if tok.kind != "name" or not JOINT_NAME.fullmatch(tok.text):
            raise self.error("expected an action: qN += step, qN -= step, qN HOLD or OUT_OF_REACH")
        self.i += 1
        joint = int(tok.text[1:])
        where = (tok.line, tok.col)
        if self.accept("kw", "HOLD"):
            return Action("hold", joint, where=where)
        if self.accept("op", "="):
            same = self.expect("name", what=f"{tok.text} (as in '{tok.text} = {tok.text}')")
            if same.text != tok.text:
                raise self.error(f"only '{tok.text} = {tok.text}' (hold) is allowed", same)
            return Action("hold", joint, where=where)
        op = self.accept("op", "+=") or self.accept("op", "-=")
        if op is None:
            raise self.error(f"expected '+=', '-=', '=' or HOLD after {tok.text}")
        return Action("inc" if op.text == "+=" else "dec", joint, self.expr(), where=where)

    def condition(self):
        node = self.conjunction()
        while (tok := self.accept("kw", "OR")):
            node = self.node(tok, Binary("or", node, self.conjunction()))
        return node

    def conjunction(self):
        node = self.negation()
        while (tok := self.accept("kw", "AND")):
            node = self.node(tok, Binary("and", node, self.negation()))
        return node

    def negation(self):
        if (tok := self.accept("kw", "NOT")):
            self.enter(tok)
            node = self.node(tok, Unary("not", self.negation()))
            self.nesting -= 1
            return node
        failed = None  # (token index, error) of the condition tried first
        if self.tok.kind == "op" and self.tok.text == "(":
            # '(' opens either a condition or an expression: try the condition first.
            save, nesting, opener = self.i, self.nesting, self.tok
            self.enter(opener)
            self.i += 1
            try:
                node = self.condition()
                self.close(opener)
            except RuleLimitError:
                raise
            except RuleSyntaxError as exc:
                failed = (self.i, exc)
            else:
                if self._at_expression_operator():  # no expression holds a condition
                    raise self._condition_as_number(opener)
                self.nesting = nesting
                return node
            self.i, self.nesting = save, nesting
        try:
            return self.comparison()
        except RuleLimitError:
            raise
        except RuleSyntaxError:
            # both readings fail: report the one that read farther (the user's likelier meaning)
            if failed is not None and failed[0] > self.i:
                raise failed[1] from None
            raise

    def _at_expression_operator(self) -> bool:
        return self.tok.kind == "op" and self.tok.text in _OPERAND_FOLLOWERS

    def _condition_as_number(self, opener: Token) -> RuleSyntaxError:
        """The error of a condition in parentheses used as a number: '(a < b) < c'."""
        chained = _NO_CHAIN if self.tok.text in COMPARISONS else ""
        error = self.error(f"a condition in parentheses (opened at line {opener.line}, column "
                           f"{opener.col}) is true or false, not a number to compare or compute "
                           "with")
        return RuleSyntaxError(f"{error}{chained}")

    def comparison(self):
        left = self.expr()
        tok = self.tok
        if tok.kind == "op" and tok.text in COMPARISONS:
            self.i += 1
            return self.node(tok, Binary(tok.text, left, self.expr()))
        raise self.error("expected a comparison (<, <=, >, >=, ==, !=)")

    def expr(self):
        node = self.term()
        while self.tok.kind == "op" and self.tok.text in ("+", "-"):
            tok = self.tok
            self.i += 1
            node = self.node(tok, Binary(tok.text, node, self.term()))
        return node

    def term(self):
        node = self.unary()
        while self.tok.kind == "op" and self.tok.text in ("*", "/"):
            tok = self.tok
            self.i += 1
            node = self.node(tok, Binary(tok.text, node, self.unary()))
        return node

    def unary(self):
        tok = self.tok
        if self.accept("op", "-") or self.accept("op", "+"):
            self.enter(tok)
            node = self.unary()
            self.nesting -= 1
            return self.node(tok, Unary("-", node)) if tok.text == "-" else node
        return self.power()

    def power(self):
        base = self.atom()
        if (tok := self.accept("op", "^")):
            self.enter(tok)
            node = self.node(tok, Binary("^", base, self.unary()))
            self.nesting -= 1
            return node
        return base

    def atom(self):
        tok = self.tok
        if tok.kind == "num":
            self.i += 1
            return self.node(tok, Num(float(tok.text)))
        if tok.kind == "name":
            self.i += 1
            if self.tok.kind == "op" and self.tok.text == "(":
                raise RuleSyntaxError(
                    f"{self.at(tok)}: '{tok.text}(' reads as a function call, "
                    "and the rule language has none (only + - * / ^, |x| and comparisons; a "
                    "product needs its *)")
            return self.node(tok, Name(tok.text, tok))
        if tok.kind == "op" and tok.text in ("(", "|"):
            self.enter(tok)
            self.i += 1
            node = self.expr()
            self.close(tok)
            if tok.text == "|":
                node = self.node(tok, Unary("abs", node))
            self.nesting -= 1
            return node
        raise self.error("expected a number, a name, '(' or '|'")


# --------------------------------------------------------------------------- compiler
def _div(a: float, b: float) -> float:
    """``a / b`` as IEEE 754 doubles: x / 0 is +-inf, 0 / 0 NaN (Python raises instead)."""
    try:
        return a / b
    except ZeroDivisionError:
        if a == 0 or a != a:
            return math.nan
        return math.copysign(math.inf, a) * math.copysign(1.0, b)


def _pow(a: float, b: float) -> float:
    """``a ^ b``, total: 0 ^ -1 is inf, an overflow +-inf, a complex result (a negative base to
    a fractional power) NaN (Python raises, or returns a complex number, or overflows one:
    ``(-1e300) ^ 1.5``), as C99's pow."""
    if a < 0 and math.isfinite(a) and math.isfinite(b) and b != math.floor(b):
        return math.nan
    try:
        r = a ** b
    except ZeroDivisionError:
        return math.inf
    except OverflowError:  # a negative base has a whole exponent here (see above)
        return -math.inf if a < 0 and b % 2 == 1 else math.inf
    return r


def _is_square(node: Node) -> bool:
    """``x ^ 2``, which both compilers (Python and C) write as the product ``x * x`` (no pow
    call, the same double): they must agree on it bit for bit."""
    return isinstance(node, Binary) and node.op == "^" and node.right == Num(2.0)


_HELPERS = {"_div": _div, "_pow": _pow, "abs": abs, "__builtins__": {}}
_ARITHMETIC = {"+", "-", "*", "/", "^", "abs"}


def _names_in(node: Node | None) -> list[tuple[str, Token]]:
    if node is None:
        return []
    if isinstance(node, Name):
        return [(node.name, node.tok)]
    return [n for child in children(node) for n in _names_in(child)]


def _subtrees(node: Node):
    """The node and every node below it."""
    yield node
    for child in children(node):
        yield from _subtrees(child)


def _by_number(node: Node) -> bool:
    """A division by a nonzero number (Python's division, which cannot raise)."""
    return isinstance(node, Binary) and node.op == "/" and isinstance(node.right, Num) \
        and node.right.value != 0


def _by_variable(node: Node) -> bool:
    """A division by anything else: 0 possible, so the compiled code needs ``_div``."""
    return isinstance(node, Binary) and node.op == "/" and not _by_number(node)


def _surely_evaluated_children(node: Node) -> tuple:
    """The children Python evaluates whenever it evaluates the node (of ``a AND b`` and
    ``a OR b`` only ``a``)."""
    if isinstance(node, Binary) and node.op in ("and", "or"):
        return (node.left,)
    return children(node)


def _evaluated(node: Node):
    """The node and the nodes below it that Python evaluates whenever it evaluates the node."""
    yield node
    for child in _surely_evaluated_children(node):
        yield from _evaluated(child)


def _worth_sharing(node: Node) -> bool:
    """An arithmetic operation, or a comparison of results of some: a value worth keeping."""
    if not isinstance(node, (Unary, Binary)) or node.op in ("and", "or", "not"):
        return False
    return any(isinstance(n, (Unary, Binary)) and n.op in _ARITHMETIC for n in _subtrees(node))


# Python's precedence levels, lowest first: parentheses go where the tree needs them
_IF_ELSE, _OR, _AND, _NOT, _COMPARE, _SUM, _PRODUCT, _NEGATIVE, _ATOM = range(9)
_LEVEL = {"or": _OR, "and": _AND, "+": _SUM, "-": _SUM, "*": _PRODUCT, "/": _PRODUCT}


def _py(node: Node, temps, local=lambda node: None, level: int = _IF_ELSE) -> str:
    """Python source of a checked tree (never of the file's text), parenthesised if its
    operator binds less than ``level``; ``temps`` numbers the temporaries (an
    ``itertools.count`` per compiled rule base); ``local(node)`` names the local that holds
    the value of a subtree computed already (or is None)."""
    return _parenthesised(_py_level(node, temps, local), level)


def _parenthesised(source: tuple[str, int], level: int) -> str:
    text, own = source
    return text if own >= level else f"({text})"


def _py_level(node: Node, temps, local) -> tuple[str, int]:
    """(Python source, precedence level of its outermost operator)."""
    if (name := local(node)) is not None:
        return name, _ATOM
    if isinstance(node, Num):
        return repr(node.value), _ATOM  # finite and not negative: checked by the tokenizer
    if isinstance(node, Name):
        return f"v_{node.name}", _ATOM
    if isinstance(node, Unary) and node.op == "abs":
        return f"abs({_py(node.arg, temps, local)})", _ATOM
    if isinstance(node, Unary):
        level = _NEGATIVE if node.op == "-" else _NOT
        return ("-" if node.op == "-" else "not ") + _py(node.arg, temps, local, level), level
    op = node.op
    left, right = _py_level(node.left, temps, local), _py_level(node.right, temps, local)
    if _is_square(node):  # squares (RULE 0's r^2): no call, same value
        if left[0].isidentifier() or isinstance(node.left, Num):
            return f"{left[0]} * {left[0]}", _PRODUCT
        t = f"_t{next(temps)}"
        return f"({t} := {left[0]}) * {t}", _PRODUCT
    if op == "^":
        return f"_pow({left[0]}, {right[0]})", _ATOM
    if op == "/" and _by_variable(node) and any(map(_by_variable, _subtrees(node.left))):
        return f"_div({left[0]}, {right[0]})", _ATOM  # the source stays linear in the tree
    level = _LEVEL.get(op, _COMPARE)  # left-associative; comparisons never chain
    a = _parenthesised(left, level + (level == _COMPARE))
    b = _parenthesised(right, level + 1)
    if op == "/" and _by_variable(node):
        # Python's division, _div when the divisor is 0 (then a, written twice, is evaluated
        # there instead)
        if b.isidentifier():
            return f"{a} / {b} if {b} else _div({left[0]}, {b})", _IF_ELSE
        t = f"_t{next(temps)}"
        return f"{a} / {t} if ({t} := {right[0]}) else _div({left[0]}, {t})", _IF_ELSE
    return f"{a} {op} {b}", level  # a division by a nonzero number cannot raise


def _moves(rule: Rule) -> dict[int, Action]:
    """Joint -> the action that sets its step: the rule's ``+=`` or ``-=`` on it (one action per
    joint, checked when parsed; a joint it holds keeps 0.0)."""
    return {a.joint: a for a in rule.actions if a.kind in ("inc", "dec")}


@dataclass(frozen=True)
class _Test:
    """How the compiled function tests one rule that moves joints."""

    rule: Rule
    keyword: str  # "if", or "elif" after rules that each share a joint with this one
    guard: tuple[int, ...]  # joints an earlier rule may have set (flags freeN), checked first
    returns: bool  # it sets every joint: when it fires, the scan is over


def _plan(rules: list[Rule], n_joints: int) -> list[_Test]:
    """The tests of the rules that move joints, in file order. A rule fires when its condition
    holds and none of its joints is set. One that sets every joint returns when it fires (then
    nothing else had fired), so the rules after it know it set nothing. One that shares a
    joint with each rule of the chain just before it is an ``elif`` of that chain: if one of
    those fired, it could not. Its guard is what is left: the joints a rule before the chain
    may have set (with first-match rule bases such as ITG+, none). A chain has at most
    :data:`MAX_ELIF` rules (Python's compiler recurses on each ``elif``)."""
    tests, maybe, chain, before_chain = [], set(), [], set()
    for r in rules:
        joints = r.joints
        returns = len(joints) == n_joints
        if not returns and 0 < len(chain) < MAX_ELIF and all(joints & c for c in chain):
            tests.append(_Test(r, "elif", tuple(sorted(joints & before_chain)), False))
            chain.append(joints)
        else:
            tests.append(_Test(r, "if", tuple(sorted(joints & maybe)), returns))
            chain, before_chain = ([] if returns else [joints]), set(maybe)
        if not returns:
            maybe |= joints
    return tests


def _steps(rule: Rule) -> list[Node]:
    """The steps of a rule's moves (``+=``, ``-=``)."""
    return [a.step for a in _moves(rule).values()]


def _last_readers(tests: list[_Test], lets: dict) -> dict[str, int]:
    """Definition name -> the last test (its index) whose condition or steps read it, directly
    or through other definitions (``lets``: name -> `Definition`, in file order)."""
    last = {}
    for i, t in enumerate(tests):
        for node in [t.rule.condition, *_steps(t.rule)]:
            last.update((name, i) for name, _ in _names_in(node) if name in lets)
    for d in reversed(lets.values()):  # its readers first: a definition reads only those above it
        if d.name in last:
            for name, _ in _names_in(d.expr):
                if name in lets:
                    last[name] = max(last.get(name, -1), last[d.name])
    return last


def _definitions_before(tests: list[_Test], i: int, last: dict[str, int], reads) -> set[str]:
    """The definitions computed before test i, an ``if``, for its whole chain (nothing can
    stand before an ``elif``); ``reads(nodes)``: the definitions nodes read that are not
    computed yet, ``last``: :func:`_last_readers`. A definition is computed before the first
    test that reads it; one that only a rule's steps read, before that rule's test too if a
    later rule reads it and the rule does not return, else in its body."""
    before, j = set(), i
    while j == i or (j < len(tests) and tests[j].keyword == "elif"):
        before |= reads([tests[j].rule.condition])
        # (a rule that returns when it fires leaves nothing for the rules after it: its
        # steps' definitions go in its body alone)
        if not tests[j].returns:
            before |= {name for name in reads(_steps(tests[j].rule)) if last[name] > j}
        j += 1
    return before


@dataclass
class _Scope:
    """What a point of the compiled function has computed: definitions (name -> True; with
    every definition they read), and subexpressions (by :meth:`_Writer.key`) kept in locals."""

    defined: ChainMap = field(default_factory=ChainMap)
    known: ChainMap = field(default_factory=ChainMap)

    def inner(self) -> "_Scope":
        """The scope of a block inside (what it computes is not known after it; what the
        block outside computes is, read through, not copied)."""
        return _Scope(self.defined.new_child(), self.known.new_child())


def _conjuncts(node: Node) -> list[Node]:
    """``a AND b AND c`` as [a, b, c], left to right (the order Python evaluates them)."""
    if isinstance(node, Binary) and node.op == "and":
        return _conjuncts(node.left) + _conjuncts(node.right)
    return [node]


def _conjunction(nodes: list[Node]) -> Node:
    node = nodes[0]
    for other in nodes[1:]:
        node = Binary("and", node, other)
    return node


def _definitions_read(nodes, lets: dict, computed=frozenset()) -> set[str]:
    """The names of the definitions (``lets``: name -> `Definition`) that ``nodes`` read,
    directly or through other definitions, but for those in ``computed`` and what they read
    (a scope's :attr:`_Scope.defined`: a definition is computed after those it reads)."""
    found, names = set(), [name for node in nodes for name, _ in _names_in(node)]
    while names:
        name = names.pop()
        if name in lets and name not in found and name not in computed:
            found.add(name)
            names += [n for n, _ in _names_in(lets[name].expr)]
    return found


class _Writer:
    """The compiled function's lines: definitions computed where first needed, subexpressions
    evaluated more than once computed once."""

    def __init__(self, definitions, tested):
        """``tested``: for each rule in the order tested, its condition and its steps."""
        self.lines: list[str] = []
        self.temps, self.shared = itertools.count(), itertools.count()
        self.lets = {d.name: d for d in definitions}  # in file order
        self.order = {name: k for k, name in enumerate(self.lets)}  # name -> its place
        self._keys: dict[int, tuple] = {}  # id(node) -> (node, key): the node kept alive, so
        # that no node made later (the operands a split AND regroups) reuses its id
        self._shapes: dict = {}  # shape -> key
        self._at: dict[int, list[int]] = {}  # key -> the rules that surely evaluate it if tested
        for i, nodes in enumerate(tested):  # (the condition; the steps if the rule fires)
            for node in (n for node in nodes for n in _evaluated(node)):
                self._at.setdefault(self.key(node), []).append(i)

    def line(self, depth: int, text: str) -> None:
        self.lines.append("    " * depth + text)

    def py(self, node: Node, scope: _Scope, level: int = _IF_ELSE) -> str:
        return _py(node, self.temps, lambda n: scope.known.get(self.key(n)), level)

    def key(self, node: Node) -> int:
        """A number per shape (the tree without its tokens): equal keys, equal values, since
        every operation is a pure function of its operands."""
        known = self._keys.get(id(node))
        if known is not None:
            return known[1]
        shape = (repr(node.value) if isinstance(node, Num) else node.name
                 if isinstance(node, Name) else (node.op, *map(self.key, children(node))))
        key = self._shapes.setdefault(shape, len(self._shapes))
        self._keys[id(node)] = (node, key)
        return key

    def share(self, nodes, uses, scope: _Scope, depth: int) -> None:
        """Before code that evaluates ``nodes``: compute into locals the largest of their
        subexpressions evaluated with them (:func:`_evaluated`) and evaluated at least twice
        in all, as ``uses(key)`` counts (here and in the code that can follow)."""
        chosen: dict[int, Node] = {}

        def visit(node):
            key = self.key(node)
            if key in scope.known or key in chosen:
                return
            if uses(key) >= 2 and _worth_sharing(node):
                chosen[key] = node
                return
            for child in _surely_evaluated_children(node):
                visit(child)

        for node in nodes:
            visit(node)
        # the smaller first: one may be part of a larger one (used elsewhere too)
        for key, node in sorted(chosen.items(), key=lambda kv: sum(1 for _ in _subtrees(kv[1]))):
            local = f"_c{next(self.shared)}"
            self.line(depth, f"{local} = {self.py(node, scope)}")
            scope.known[key] = local

    def share_before_test(self, i: int, scope: _Scope, condition: Node) -> None:
        """Before the test of the i-th rule tested (which evaluates its condition whenever
        reached: no elif, no guard), what ``condition`` (the rule's, or the part of it tested
        first) shares with itself and what follows."""
        def uses(key):
            at = self._at.get(key, ())
            return len(at) - bisect.bisect_left(at, i)

        self.share([condition], uses, scope, 1)

    def share_in_body(self, steps, scope: _Scope, depth: int = 2) -> None:
        """At the start of a rule's body, what its steps share."""
        counts = Counter(self.key(n) for node in steps for n in _subtrees(node))
        self.share(steps, counts.__getitem__, scope, depth)

    def deferred(self, condition: Node, scope: _Scope):
        """``a AND b AND ...`` whose later operands read definitions the first one does not
        (nor ``scope``): (the first operand, the later ones, those definitions), so that the
        definitions are computed only where the first operand holds (ITG+'s near-base
        predictions, read only near the base); else None."""
        terms = _conjuncts(condition)
        lazy = self.reads(terms[1:], scope) - self.reads(terms[:1], scope)
        return (terms[0], _conjunction(terms[1:]), lazy) if lazy else None

    def reads(self, nodes, scope: _Scope) -> set[str]:
        """The definitions ``nodes`` read, directly or through other definitions, that
        ``scope`` lacks."""
        return _definitions_read(nodes, self.lets, scope.defined)

    def define(self, names: set[str], scope: _Scope, depth: int) -> None:
        """Compute the definitions ``names`` that ``scope`` lacks, and those they read, in file
        order (a definition reads only those above it)."""
        names = {name for name in names if name not in scope.defined}
        names |= self.reads([self.lets[name].expr for name in names], scope)
        for name in sorted(names, key=self.order.__getitem__):
            self.line(depth, f"v_{name} = {self.py(self.lets[name].expr, scope)}")
            scope.defined[name] = True


#: An unknown name's error lists the LETs known there up to this many; beyond, it counts them.
MAX_LETS_LISTED = 40


@dataclass
class RuleBase:
    """A compiled rule base for one arm.

    Parameters
    ----------
    rules : parsed rules.
    n_joints : joints the arm has (rules naming others are refused).
    links_mm : link lengths bound to ``L1..Ln`` and ``L``.
    sL : the lengths' largest standard error (mm), bound to ``sL``
        (:attr:`itg_vision.identify.ArmGeometry.length_se_mm`).
    h : the LEDs' stand-off along the pitch axis (mm), bound to ``h``
        (:attr:`itg_vision.identify.ArmGeometry.standoff_mm`).
    f, S, w : gain (deg/mm), fixed step (deg), tolerance (mm).
    servo_step : the file declares ``#! S is the servo limit`` (see the module docstring).
    base_axis_mm : where the arm's vertical base axis crosses the xy plane (mm), measured at
        start-up; the rules see every position (set point and LEDs) relative to it, as they
        are written: with the base axis at x = y = 0.
    """

    rules: list[Rule]
    n_joints: int
    links_mm: tuple[float, ...]
    sL: float = 0.0
    h: float = 0.0
    f: float = PARAM_DEFAULTS["f"]
    S: float = PARAM_DEFAULTS["S"]
    w: float = PARAM_DEFAULTS["w"]
    source: str = "<rules>"
    servo_step: bool = False
    base_axis_mm: tuple[float, float] = (0.0, 0.0)
    definitions: tuple[Definition, ...] = ()
    python_source: str = field(default="", repr=False)
    _fn: object = field(default=None, repr=False)
    #: every name a rule or a definition reads (set once, when compiled)
    names_read: frozenset = field(default=frozenset(), repr=False)

    @classmethod
    def from_text(cls, text: str, n_joints: int, links_mm, source: str = "<rules>", **params):
        _check_arguments(n_joints, links_mm, params)
        parser = _Parser(tokenize(text, source), source)
        rules = parser.rules()
        lines = text.split("\n")  # the tokenizer's lines
        rules = [replace(r, text=_statement_text(lines, r)) for r in rules]
        declared = [(k, line) for k, line in enumerate(lines, 1) if line.lstrip().startswith("#!")]
        for k, line in declared:  # a '#!' line is the parser's: no slips
            if not SERVO_STEP.fullmatch(line):
                raise UserError(f"{source}:{k}: {clip(line.strip())!r} is not a declaration "
                                "the parser knows (the only one: '#! S is the servo limit', "
                                "a line of its own); a comment starts with '#' alone")
        servo_step = bool(declared)
        if servo_step and "S" not in params:
            raise UserError(f"{source}: S is the servo limit here (its '#! S is the servo limit' "
                            "line): give S, the largest joint step per iteration in deg")
        rb = cls(rules, n_joints, tuple(float(v) for v in links_mm), source=source,
                 servo_step=servo_step,
                 definitions=tuple(parser.definitions), **params)
        rb._check()
        rb.names_read = frozenset(n for node in rb._nodes() for n, _ in _names_in(node))
        rb.python_source = rb._source()
        rb._fn = rb._compile(rb.python_source)
        return rb

    @classmethod
    def from_file(cls, path: str | Path, n_joints: int, links_mm, **params) -> "RuleBase":
        path = Path(path)
        text = read_text(path, "rule file")
        return cls.from_text(text, n_joints, links_mm, source=str(path), **params)

    def uses(self, name: str) -> bool:
        """Whether a rule or a definition reads ``name`` (a parameter such as ``f``)."""
        return name in self.names_read

    def params(self) -> dict:
        """The parameters its rules read, by field name with units (``gain_deg_per_mm`` for f,
        ``step_deg`` for S, ``tolerance_mm`` for w)."""
        values = {"f": self.f, "S": self.S, "w": self.w}
        return {field_: values[name] for name, field_ in PARAM_FIELDS.items() if self.uses(name)}

    @property
    def uses_encoders(self) -> bool:
        """Whether a rule reads a joint angle ``q1..qn`` (then the loop passes the encoders)."""
        return any(self.uses(f"q{i}") for i in range(1, self.n_joints + 1))

    def with_links(self, links_mm, base_axis_mm=(0.0, 0.0), sL: float = 0.0,
                   h: float = 0.0) -> "RuleBase":
        """The same compiled rules with ``L1..Ln`` bound to other lengths, ``sL`` to their
        standard error, ``h`` to the LEDs' stand-off and the base axis at another point
        (measured ones)."""
        links = tuple(float(v) for v in links_mm)
        if len(links) != len(self.links_mm):
            raise ValueError(f"{len(self.links_mm)} link lengths expected, got {len(links)}")
        axis = tuple(float(v) for v in base_axis_mm)
        return replace(self, links_mm=links, base_axis_mm=(axis[0], axis[1]), sL=float(sL),
                       h=float(h))

    # -------------------------------------------------------------- checks
    @property
    def known_names(self) -> set[str]:
        joints = {f"q{i}" for i in range(1, self.n_joints + 1)}
        links = {f"L{i}" for i in range(1, len(self.links_mm) + 1)} | {"L", "sL", "h"}
        markers = (set(MARKER_NAMES) - (set(ELBOW_NAMES) if self.n_joints == 1 else set())
                   - (set(AXIS_NAMES) if self.n_joints != 3 else set()))
        return markers | set(PARAM_NAMES) | joints | links

    def _check(self) -> None:
        if not self.rules:
            raise UserError(f"{self.source}: no rules found")
        known = self.known_names
        defined: dict[str, int] = {}  # LET name -> its line
        visible = set(known)  # the built-in names and the LETs checked so far
        for d in self.definitions:
            own = next((tok for name, tok in _names_in(d.expr) if name == d.name), None)
            if own is not None and d.name not in known and d.name not in defined:
                raise UserError(f"{self.source}:{own.line}:{own.col}: LET {d.name} uses "
                                f"{d.name!r} itself: a name has one value, from one expression, "
                                "and rules keep nothing between iterations; give the new value "
                                "a new name")
            self._check_names([d.expr], visible)
            if d.name in known or d.name in defined or re.fullmatch(r"q\d+|L\d+", d.name):
                first = (f"LET on line {defined[d.name]}" if d.name in defined else
                         "a built-in name" if d.name in known else
                         f"reserved: {d.name[0]}N names {_RESERVED[d.name[0]]}")
                raise UserError(f"{self.source}:{d.line}:{d.col}: {d.name!r} is already {first}")
            defined[d.name] = d.line
            visible.add(d.name)
        seen: dict[int, int] = {}
        visible = set(known)  # the names known at the rule
        lets, above = self.definitions, 0  # the LETs before the rule: lets[:above]
        for r in self.rules:  # in file order, as the definitions
            if r.number in seen:
                raise UserError(f"{self.source}:{r.line}:{r.col}: RULE {r.number} is defined twice "
                                f"(first on line {seen[r.number]})")
            seen[r.number] = r.line
            # the LETs before the rule, on the lines above or before it on its own line
            while above < len(lets) and (lets[above].line, lets[above].col) < (r.line, r.col):
                visible.add(lets[above].name)
                above += 1
            self._check_names([r.condition] + [a.step for a in r.actions], visible)
            for a in r.actions:
                if a.kind != "out" and not 1 <= a.joint <= self.n_joints:
                    raise self._for_another_arm(a.where, f"RULE {r.number} "
                                                f"{'holds' if a.kind == 'hold' else 'moves'} "
                                                f"q{a.joint}, but the arm has {self.n_joints} "
                                                "joint(s)")
            if r.out_of_reach and len(r.actions) > 1:
                out = next(a for a in r.actions if a.kind == "out")
                raise UserError(f"{self.source}:{out.where[0]}:{out.where[1]}: OUT_OF_REACH must be "
                                "a rule's only action")
        if not any(not r.out_of_reach for r in self.rules):
            raise UserError(f"{self.source}: no rule moves a joint")

    def unmoved_joints(self) -> list[str]:
        """Joints of the arm that no rule moves or holds (``q2`` for Table 1 on a two-link arm):
        a rule base written for fewer joints. ``qN HOLD`` names a joint kept still on purpose."""
        moved = {a.joint for r in self.rules for a in r.actions if a.kind in ("inc", "dec", "hold")}
        return [f"q{j}" for j in range(1, self.n_joints + 1) if j not in moved]

    def _nodes(self) -> list:
        """The expressions of the definitions and rules (conditions, steps; None for a hold)."""
        nodes = [d.expr for d in self.definitions]
        return nodes + [n for r in self.rules for n in [r.condition] + [a.step for a in r.actions]]

    def _for_another_arm(self, where: tuple[int, int], what: str) -> ForAnotherArm:
        """The error ``what`` at ``where`` (line, column) of a name the arm lacks, with the
        fewest joints an arm needs for every joint, link and LED the rule base names."""
        names = [n for node in self._nodes() for n, _ in _names_in(node)]
        joints = [int(n[1:]) for n in names if re.fullmatch(r"[qL]\d+", n)]
        joints += [a.joint for r in self.rules for a in r.actions if a.kind != "out"]
        joints += [2] if set(names) & set(ELBOW_NAMES) else []
        joints += [3] if set(names) & set(AXIS_NAMES) else []
        return ForAnotherArm(f"{self.source}:{where[0]}:{where[1]}: {what}", max(joints))

    def _check_names(self, nodes, known: set[str]) -> None:
        for name, tok in (n for node in nodes for n in _names_in(node)):
            where = (tok.line, tok.col)
            if name in ELBOW_NAMES and name not in known:  # NaN: its comparisons never hold
                raise self._for_another_arm(where, f"{name!r} reads the elbow LED, but a "
                                                   "one-link arm has no elbow")
            if name in AXIS_NAMES and name not in known:
                raise self._for_another_arm(where, f"{name!r} reads the pitch axis, which only "
                                                   "a three-link arm has")
            if name not in known and re.fullmatch(r"L\d+", name):
                raise self._for_another_arm(where, f"{name!r} is link {name[1:]}'s length, but "
                                                   f"only {len(self.links_mm)} link length(s) "
                                                   "were given (links_mm)")
            if name not in known and re.fullmatch(r"q\d+", name):
                raise self._for_another_arm(where, f"{name!r} is joint {name[1:]}'s angle, but "
                                                   f"the arm has {self.n_joints} joint(s)")
            if name not in known:
                later = next((d for d in self.definitions if d.name == name), None)
                if later is not None:  # defined, but below its use
                    raise UserError(f"{self.source}:{tok.line}:{tok.col}: unknown name "
                                    f"{name!r} here: the LET on line {later.line} defines it "
                                    "below, and a LET must come before the rules and LETs that "
                                    "use it")
                alike = sorted(k for k in known if k.lower() == name.lower())  # not by hash
                hint = f"; did you mean {alike[0]!r}? names are case-sensitive" if alike else ""
                raise UserError(f"{self.source}:{tok.line}:{tok.col}: unknown name {name!r} "
                                f"(known: {self._known_shown(known)}){hint}")

    def _known_shown(self, known: set[str]) -> str:
        """The names ``known`` at a point of the file, for an unknown name's error: all of
        them, or the built-in ones and how many LETs above where a file has more than
        :data:`MAX_LETS_LISTED` (a file of 30,000 LETs made an error line of 30,000 names)."""
        lets = known - self.known_names
        if len(lets) <= MAX_LETS_LISTED:
            return ", ".join(sorted(known))
        return (", ".join(sorted(known & self.known_names))
                + f", and the {len(lets)} LETs above it")

    # -------------------------------------------------------------- compile
    def _source(self) -> str:
        """The Python function the rules compile to (kept as :attr:`python_source`: what runs,
        generated from the checked syntax tree, never from the file's text): out-of-reach rules
        first, then the others as :func:`_plan` tests them, definitions where
        :func:`_definitions_before` puts them, and subexpressions evaluated more than once
        computed once (:meth:`_Writer.share`)."""
        n = self.n_joints
        out_of_reach = [r for r in self.rules if r.out_of_reach]
        tests = _plan([r for r in self.rules if not r.out_of_reach], n)
        out = _Writer(self.definitions, [[r.condition] for r in out_of_reach] + [
            [t.rule.condition, *_steps(t.rule)] for t in tests])
        args = ", ".join(f"v_{m}" for m in MARKER_NAMES)
        qs = "".join(f"v_q{i}, " for i in range(1, n + 1))
        links = ", ".join(f"v_L{i}" for i in range(1, len(self.links_mm) + 1))
        out.line(0, f"def _itg_step({args}, {qs}v_f, v_S, v_w, v_L, {links}, v_sL, v_h):")
        top = _Scope()
        for i, r in enumerate(out_of_reach):
            out.define(out.reads([r.condition], top), top, 1)
            out.share_before_test(i, top, r.condition)
            out.line(1, f"if {out.py(r.condition, top)}:")
            out.line(2, f"return None, ({r.number},)")
        scanning = [t for t in tests if not t.returns]  # rules whose firing does not end the scan
        stepped = sorted({j for t in scanning for j in _moves(t.rule)})
        flagged = sorted({j for t in tests for j in t.guard})
        for j in stepped:
            out.line(1, f"dq{j} = 0.0")
        for j in flagged:
            out.line(1, f"free{j} = True")
        if scanning:
            out.line(1, "fired = []")
        last = _last_readers(tests, out.lets)
        for i, t in enumerate(tests):
            # an `if` that no `elif` follows may nest: `if a:` then the definitions only `b`
            # reads, then `if b:` (the same as `if a and b:` after computing them all)
            alone = t.keyword == "if" and not t.guard and (
                i + 1 == len(tests) or tests[i + 1].keyword == "if")
            first, then, lazy = (alone and out.deferred(t.rule.condition, top)) or (None, None, set())
            scope, depth = top, 1
            if t.keyword == "if":
                before = _definitions_before(tests, i, last, lambda nodes: out.reads(nodes, top))
                out.define(before - lazy, top, 1)
            if t.keyword == "if" and not t.guard:
                out.share_before_test(len(out_of_reach) + i, top, first or t.rule.condition)
            guard = "".join(f"free{j} and " for j in t.guard)
            if first is not None:
                out.line(1, f"if {out.py(first, top)}:")
                scope, depth = top.inner(), 2
                out.define(lazy, scope, 2)
                condition = out.py(then, scope)
            else:
                condition = out.py(t.rule.condition, top, _AND if t.guard else _IF_ELSE)
            out.line(depth, f"{t.keyword} {guard}{condition}:")
            body, moves, depth = scope.inner(), _moves(t.rule), depth + 1
            steps = [a.step for a in moves.values()]
            out.define(out.reads(steps, body), body, depth)
            out.share_in_body(steps, body, depth)
            dq = {j: "-" + out.py(a.step, body, _NEGATIVE) if a.kind == "dec" else
                  out.py(a.step, body) for j, a in moves.items()}
            if t.returns:
                values = ", ".join(dq.get(j, "0.0") for j in range(1, n + 1))
                out.line(depth, f"return [{values}], [{t.rule.number}]")
                continue
            for j, value in dq.items():
                out.line(depth, f"dq{j} = {value}")
            for j in sorted(t.rule.joints & set(flagged)):
                out.line(depth, f"free{j} = False")
            out.line(depth, f"fired.append({t.rule.number})")
        values = ", ".join(f"dq{j}" if j in stepped else "0.0" for j in range(1, n + 1))
        out.line(1, f"return [{values}], {'fired' if scanning else '[]'}")
        return "\n".join(out.lines) + "\n"

    def _compile(self, source: str):
        namespace: dict = dict(_HELPERS)
        try:
            code = compile(source, f"<compiled {self.source}>", "exec")
        except (SyntaxError, RecursionError, MemoryError) as exc:  # beyond the stated limits
            raise UserError(f"{self.source}: rule base too large to compile "
                            f"({type(exc).__name__})") from None
        exec(code, namespace)  # noqa: S102 - source generated from the checked tree
        return namespace["_itg_step"]

    @property
    def argument_names(self) -> tuple[str, ...]:
        """Names of :meth:`arguments`, in order."""
        return (*MARKER_NAMES, *(f"q{i}" for i in range(1, self.n_joints + 1)), *PARAM_NAMES,
                "L", *(f"L{i}" for i in range(1, len(self.links_mm) + 1)), "sL", "h")

    # -------------------------------------------------------------- run
    @property
    def compiled(self):
        """The compiled rule function; it takes :meth:`arguments` and returns ``(dq, fired)``:
        a list of one step per joint (deg) and a list of the fired rules' numbers, in firing
        order; when an OUT_OF_REACH rule fires, ``(None, (number,))`` (:meth:`step` turns both
        into a :class:`~itg_vision.contracts.Step`)."""
        return self._fn

    def arguments(self, desired_mm, markers, q_deg) -> tuple[float, ...]:
        """The compiled function's arguments, in its order, as plain Python floats (with NaN,
        comparisons are False and raise no warning); x, y relative to :attr:`base_axis_mm`."""
        d, g, e, a = desired_mm, markers.gripper_mm, markers.elbow_mm, markers.pitch_axis
        ox, oy = self.base_axis_mm
        xd, yd, zd = float(d[0]) - ox, float(d[1]) - oy, float(d[2])
        xg, yg, zg = float(g[0]) - ox, float(g[1]) - oy, float(g[2])
        xe, ye, ze = float(e[0]) - ox, float(e[1]) - oy, float(e[2])
        links = self.links_mm
        nan_q = (math.nan,) * self.n_joints  # rules that read no q are not given the encoders
        xa, ya = (math.nan, math.nan) if a is None else (float(a[0]), float(a[1]))
        return (xd, yd, zd, xg, yg, zg, xe, ye, ze,
                xd * xd + yd * yd, xg * xg + yg * yg, xe * xe + ye * ye, xa, ya,
                *(nan_q if q_deg is None else (float(q) for q in q_deg)),
                float(self.f), float(self.S), float(self.w), links[0], *links, float(self.sL),
                float(self.h))

    def step(self, desired_mm, markers, q_deg) -> Step:
        """Apply the rules once. ``markers`` has ``gripper_mm`` and ``elbow_mm`` (shape (3,))."""
        args = self.arguments(desired_mm, markers, q_deg)
        dq, fired = self._fn(*args)
        if dq is None:
            return Step(np.zeros(self.n_joints), tuple(fired), True)
        for j, v in enumerate(dq):
            if not math.isfinite(v):
                dq[j] = self._non_finite_step(j, v, fired, args)
        return Step(np.array(dq), tuple(fired), False)

    def rules_at(self, numbers) -> str:
        """Where the rules of those numbers are, for a message: ``RULE 1 (FILE:LINE), ...``."""
        line = {r.number: r.line for r in self.rules}
        return ", ".join(f"RULE {n} ({self.source}:{line[n]})" if n in line else f"RULE {n}"
                         for n in numbers)

    def _inputs_of(self, node: Node) -> list[str]:
        """The function's inputs ``node`` reads, directly or through definitions (in file
        order), each once."""
        lets = {d.name: d for d in self.definitions}
        read = _definitions_read([node], lets)
        nodes = [node] + [d.expr for d in self.definitions if d.name in read]
        return list(dict.fromkeys(n for x in nodes for n, _ in _names_in(x) if n not in lets))

    def _non_finite_step(self, j: int, value: float, fired, args) -> float:
        """A step of joint j that is not a finite number: 0 if it came from a NaN input (a
        marker not measured never moves a joint), else a `UserError` naming the rule."""
        env = dict(zip(self.argument_names, args))
        for rule in (r for n in fired for r in self.rules if r.number == n):
            for a in rule.actions:
                if a.joint != j + 1 or a.kind not in ("inc", "dec"):
                    continue
                names = self._inputs_of(a.step)
                if any(env[n] != env[n] for n in names):
                    return 0.0
                values = ", ".join(f"{n} = {env[n]:.6g}" for n in names) or "constants only"
                raise UserError(
                    f"{self.source}:{rule.line}: RULE {rule.number} gives q{j + 1} a step of "
                    f"{value} deg ({values}): division by zero, overflow or a negative number "
                    f"to a fractional power in '{clip(rule.text, 80)}'; the run is stopped")
        return 0.0


def _statement_text(lines: list[str], rule: Rule) -> str:
    """A rule's text as one line, for messages: from its 'RULE' to its last token, over as
    many lines as it spans, comments left out."""
    (line, col), (end_line, end_col) = (rule.line, rule.col), rule.end
    parts = [lines[k - 1][col - 1 if k == line else 0: end_col - 1 if k == end_line else None]
             for k in range(line, end_line + 1)]
    return " ".join(" ".join(p.split("#", 1)[0].split()) for p in parts if p.split("#", 1)[0].strip())


def resolve_rules_path(name_or_path: str) -> Path:
    """A shipped rule base by name (``table1``, ``table2``, ``three-link``) or a file path: a
    name ending in .rules or holding a folder separator is a path, any other a shipped name
    (whatever files the current folder holds: a file or folder called ``table2`` there does not
    replace the shipped ``table2``)."""
    p = Path(name_or_path)
    if names_a_path(name_or_path, (".rules",)):
        if not p.exists():
            raise UserError(not_found(p, "rule", rule_names()))
        return p
    candidate = RULES_DIR / f"{name_or_path}.rules"
    if not candidate.exists():
        shipped = rule_names()
        raise UserError(f"unknown rule base {name_or_path!r} (shipped: {', '.join(shipped)}; "
                        f"{or_a_path(name_or_path, 'a rule file', '.rules')})")
    return candidate


def _check_arguments(n_joints, links_mm, params: dict) -> None:
    """A rule base's arguments from code (files and options are checked by their readers):
    ValueError naming the first that no arm could have."""
    if not (is_whole(n_joints) and n_joints >= 1):
        raise ValueError(f"n_joints must be a whole number >= 1, got {n_joints!r}")
    unknown = sorted(set(params) - set(PARAM_NAMES))
    if unknown:
        raise ValueError(f"unknown rule parameter(s) {', '.join(unknown)} (the rules' are "
                         f"{', '.join(PARAM_NAMES)})")
    links = list(links_mm)  # L1..Ln for the rules: as many as given (tests probe with more joints)
    if not links or not all(is_real(v) and v > 0 for v in links):
        raise ValueError(f"links_mm must be finite lengths > 0 (mm), got {links}")
    for name, need, ok in (("f", "> 0", lambda v: v > 0), ("S", "> 0", lambda v: v > 0),
                           ("w", ">= 0", lambda v: v >= 0)):
        v = params.get(name)
        if v is not None and not (is_real(v) and ok(v)):
            raise ValueError(f"{name} must be a finite number {need}, got {v!r}")


def load_rules(name_or_path: str, n_joints: int, links_mm, **params) -> RuleBase:
    """A rule base for an arm with ``n_joints`` joints; refused unless its rules move or hold
    (``qN HOLD``) every one.

    ``params``: ``f`` (deg/mm), ``S`` (deg), ``w`` (mm), the rules' parameters; those not given
    take :data:`PARAM_DEFAULTS` (f 0.5, S 2, w 0.5), as ``run`` does. A rule base whose S is
    the servo limit (``#! S is the servo limit``, the ITG+ files) needs ``S`` given, here as in
    :meth:`RuleBase.from_text`: the servo's largest step per iteration."""
    try:
        rb = RuleBase.from_file(resolve_rules_path(name_or_path), n_joints, links_mm, **params)
    except ForAnotherArm as exc:
        if exc.joints <= n_joints:  # q0, or fewer links given than the arm's joints: not so
            raise
        raise UserError(f"{exc}: a rule base for another arm? (its rules are for an arm of "
                        f"{exc.joints} joints or more, this one has {n_joints}; shipped: "
                        f"{_shipped_by_arm()})") from None
    unmoved = rb.unmoved_joints()
    if unmoved:
        raise UserError(f"{rb.source}: no rule moves or holds {', '.join(unmoved)} of this "
                        f"{n_joints}-joint arm: a rule base for another arm? (shipped: "
                        f"{_shipped_by_arm()}; to keep a joint still on purpose, say so: "
                        f"{unmoved[0]} HOLD)")
    return rb


def _shipped_by_arm() -> str:
    """The shipped rule bases and their arms, for the error of a rule base for another arm:
    'table1 (one-link), itg-plus-one-link (one-link), ...'."""
    from .arm import ArmSpec, arm_names

    return ", ".join(f"{ArmSpec.from_args(a).defaults[k]} ({a})" for a in arm_names()
                     for k in ("rules", "itg_plus_rules"))


