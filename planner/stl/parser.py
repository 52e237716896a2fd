"""Recursive-descent parser for the STL syntax of docs/stl.md, "Semantics".

Grammar (loosest first; ``implies`` and ``until`` associate to the right, ``and``/``or`` chains
become one n-ary node, arithmetic is left associative)::

    spec        := implies EOF
    implies     := or (("implies" | "->") implies)?
    or          := and (("or" | "|") and)*
    and         := until (("and" | "&") until)*
    until       := unary (("until" | "U") interval until)?
    unary       := ("not" | "!") unary
                 | ("always" | "G") interval unary
                 | ("eventually" | "F") interval unary
                 | atom
    atom        := "true" | "false" | "(" implies ")" | expr cmp expr | call
    interval    := "[" number "," number "]"
    cmp         := ">=" | ">" | "<=" | "<"
    expr        := term (("+" | "-") term)*
    term        := factor (("*" | "/") factor)*
    factor      := "-" number | "-" factor | primary
    primary     := number | name | call | "(" expr ")"
    call        := name "(" (name ("," name)*)? ")"

``G``, ``F`` and ``U`` are operators only when a ``[`` follows, so they stay usable as signal
names. A ``(`` at atom level is tried as a parenthesised formula first and as arithmetic when
that fails or when an arithmetic/comparison operator follows the closing parenthesis.
``#`` starts a comment that runs to the end of the line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from planner.stl.ast import (
    RESERVED,
    Always,
    And,
    ArithOp,
    BinOp,
    BoolConst,
    Call,
    CmpOp,
    Comparison,
    Const,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Signal,
    Until,
)
from planner.stl.errors import SpecError
from planner.stl.functions import FunctionRegistry

_TOKEN = re.compile(
    r"""
    (?P<ws>[ \t\r\n]+|\#[^\n]*)
  | (?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>>=|<=|->|[><()\[\],+\-*/!&|])
    """,
    re.VERBOSE,
)
_CMP = {">=": CmpOp.GE, ">": CmpOp.GT, "<=": CmpOp.LE, "<": CmpOp.LT}
_ARITH_TOKENS = frozenset({"+", "-", "*", "/"})
_EOF = "end of input"


@dataclass(frozen=True, slots=True)
class Token:
    """A lexical token with its 1-based position."""

    kind: str  # "number", "name", "op", "eof"
    text: str
    line: int
    column: int
    offset: int

    @property
    def shown(self) -> str:
        return _EOF if self.kind == "eof" else repr(self.text)


def tokenize(text: str) -> list[Token]:
    """Split ``text`` into tokens (ending with an ``eof`` token).

    Raises:
        SpecError: a character that starts no token.
    """
    tokens: list[Token] = []
    pos, line, line_start = 0, 1, 0
    while pos < len(text):
        match = _TOKEN.match(text, pos)
        if match is None:
            raise SpecError(
                f"unexpected character {text[pos]!r}",
                line=line,
                column=pos - line_start + 1,
                token=text[pos],
                expected="a name, a number, an operator or a parenthesis",
                text=text,
            )
        kind = match.lastgroup
        assert kind is not None
        if kind != "ws":
            tokens.append(Token(kind, match.group(), line, pos - line_start + 1, pos))
        newlines = match.group().count("\n")
        if newlines:
            line += newlines
            line_start = pos + match.group().rindex("\n") + 1
        pos = match.end()
    tokens.append(Token("eof", "", line, pos - line_start + 1, pos))
    return tokens


class _Parser:
    def __init__(self, text: str, functions: FunctionRegistry | None) -> None:
        self.text = text
        self.functions = functions if functions is not None else FunctionRegistry()
        self.tokens = tokenize(text)
        self.pos = 0

    # ---- helpers

    @property
    def tok(self) -> Token:
        return self.tokens[self.pos]

    def peek(self, ahead: int = 1) -> Token:
        return self.tokens[min(self.pos + ahead, len(self.tokens) - 1)]

    def error(
        self, expected: str, token: Token | None = None, message: str | None = None
    ) -> SpecError:
        token = token or self.tok
        shown = token.shown
        return SpecError(
            message or f"expected {expected}, found {shown}",
            line=token.line,
            column=token.column,
            token=_EOF if token.kind == "eof" else token.text,
            expected=expected,
            text=self.text,
        )

    def at(self, *texts: str) -> bool:
        return self.tok.kind in ("op", "name") and self.tok.text in texts

    def expect(self, text: str) -> Token:
        if not (self.tok.kind in ("op", "name") and self.tok.text == text):
            raise self.error(repr(text))
        token = self.tok
        self.pos += 1
        return token

    def at_temporal(self, *names: str) -> bool:
        return self.tok.kind == "name" and self.tok.text in names and self.peek().text == "["

    # ---- formulas

    def spec(self) -> Formula:
        if self.tok.kind == "eof":
            raise self.error("a formula")
        formula = self.implies()
        if self.tok.kind != "eof":
            if self.tok.text in _CMP:
                raise self.error(
                    "end of input",
                    message=f"chained comparison at {self.tok.shown}: compare two expressions only",
                )
            raise self.error("'and', 'or', 'implies', 'until' or end of input")
        return formula

    def implies(self) -> Formula:
        lhs = self.or_()
        if self.at("implies", "->"):
            self.pos += 1
            return Implies(lhs, self.implies())
        return lhs

    def or_(self) -> Formula:
        items = [self.and_()]
        while self.at("or", "|"):
            self.pos += 1
            items.append(self.and_())
        return items[0] if len(items) == 1 else Or(tuple(items))

    def and_(self) -> Formula:
        items = [self.until()]
        while self.at("and", "&"):
            self.pos += 1
            items.append(self.until())
        return items[0] if len(items) == 1 else And(tuple(items))

    def until(self) -> Formula:
        lhs = self.unary()
        if self.at("until") or self.at_temporal("U"):
            self.pos += 1
            start_s, end_s = self.interval()
            return Until(lhs, self.until(), start_s, end_s)
        return lhs

    def unary(self) -> Formula:
        if self.at("not", "!"):
            self.pos += 1
            return Not(self.unary())
        if self.at("always") or self.at_temporal("G"):
            self.pos += 1
            start_s, end_s = self.interval()
            return Always(self.unary(), start_s, end_s)
        if self.at("eventually") or self.at_temporal("F"):
            self.pos += 1
            start_s, end_s = self.interval()
            return Eventually(self.unary(), start_s, end_s)
        return self.atom()

    def interval(self) -> tuple[float, float]:
        self.expect("[")
        lo_tok = self.tok
        start_s = self.number("the interval's lower bound (seconds, >= 0)")
        self.expect(",")
        end_s = self.number("the interval's upper bound (seconds)")
        self.expect("]")
        if start_s > end_s:
            raise self.error(
                "an interval [a,b] with a <= b",
                token=lo_tok,
                message=f"interval lower bound {lo_tok.text} exceeds upper bound "
                f"{self.tokens[self.pos - 2].text}",
            )
        return start_s, end_s

    def number(self, expected: str) -> float:
        if self.tok.kind != "number":
            raise self.error(expected)
        value = float(self.tok.text)
        if value == float("inf"):
            raise self.error(expected, message=f"number {self.tok.text} is too large")
        self.pos += 1
        return value

    def atom(self) -> Formula:
        tok = self.tok
        if self.at("true"):
            self.pos += 1
            return BoolConst(True)
        if self.at("false"):
            self.pos += 1
            return BoolConst(False)
        if self.at("("):
            start = self.pos
            try:
                self.pos += 1
                inner = self.implies()
                self.expect(")")
            except SpecError as formula_error:
                self.pos = start
                try:
                    return self.comparison()
                except SpecError as expr_error:
                    # Report whichever reading got further into the text.
                    key_f = (formula_error.line, formula_error.column)
                    key_e = (expr_error.line, expr_error.column)
                    raise (expr_error if key_e > key_f else formula_error) from None
            if self.tok.kind == "op" and (self.tok.text in _CMP or self.tok.text in _ARITH_TOKENS):
                # "(a + b) >= 1": the parentheses held arithmetic after all.
                self.pos = start
                return self.comparison()
            return inner
        if tok.kind == "name" and tok.text in RESERVED:
            raise self.error(
                "a formula",
                message=f"expected a formula, found keyword {tok.text!r}",
            )
        if tok.kind in ("number", "name") or self.at("-"):
            return self.comparison()
        raise self.error("a formula (comparison, function, 'true', 'false', '(' or an operator)")

    def comparison(self) -> Formula:
        lhs = self.expr()
        if self.tok.kind == "op" and self.tok.text in _CMP:
            op = _CMP[self.tok.text]
            self.pos += 1
            return Comparison(lhs, op, self.expr())
        if isinstance(lhs, Call):
            return Predicate(lhs)
        raise self.error("a comparison operator ('>=', '>', '<=', '<')")

    # ---- expressions

    def expr(self) -> Expr:
        node = self.term()
        while self.tok.kind == "op" and self.tok.text in ("+", "-"):
            op = ArithOp(self.tok.text)
            self.pos += 1
            node = BinOp(op, node, self.term())
        return node

    def term(self) -> Expr:
        node = self.factor()
        while self.tok.kind == "op" and self.tok.text in ("*", "/"):
            op = ArithOp(self.tok.text)
            self.pos += 1
            node = BinOp(op, node, self.factor())
        return node

    def factor(self) -> Expr:
        if self.at("-"):
            self.pos += 1
            if self.tok.kind == "number":
                # "-1" is the constant -1 (Neg(Const(1)) prints as "-(1)").
                value = self.number("a number")
                return Const(-value)
            return Neg(self.factor())
        return self.primary()

    def primary(self) -> Expr:
        tok = self.tok
        if tok.kind == "number":
            return Const(self.number("a number"))
        if self.at("("):
            self.pos += 1
            inner = self.expr()
            self.expect(")")
            return inner
        if tok.kind == "name":
            if tok.text in RESERVED:
                raise self.error(
                    "a signal name or a number",
                    message=f"reserved word {tok.text!r} cannot be used as a signal name",
                )
            self.pos += 1
            if self.at("("):
                return self.call(tok)
            return Signal(tok.text)
        raise self.error("a signal name, a number, a function call or '('")

    def call(self, name_tok: Token) -> Call:
        function = self.functions.get(name_tok.text)
        if function is None:
            known = ", ".join(sorted(self.functions)) or "none registered"
            raise self.error(
                "a registered function",
                token=name_tok,
                message=f"unknown function {name_tok.text!r} (known: {known})",
            )
        self.expect("(")
        args: list[str] = []
        if not self.at(")"):
            while True:
                if self.tok.kind != "name" or self.tok.text in RESERVED:
                    raise self.error(f"an identifier argument of {name_tok.text}()")
                args.append(self.tok.text)
                self.pos += 1
                if self.at(","):
                    self.pos += 1
                    continue
                break
        close = self.tok
        self.expect(")")
        if len(args) != function.arity:
            raise self.error(
                f"{function.arity} arguments",
                token=name_tok,
                message=f"function {name_tok.text!r} takes {function.arity} arguments, "
                f"got {len(args)} (call ends at line {close.line}, column {close.column})",
            )
        return Call(name_tok.text, tuple(args), function)


def parse(text: str, functions: FunctionRegistry | None = None) -> Formula:
    """Parse STL text into a :class:`~planner.stl.ast.Formula`.

    Args:
        text: the specification (may span lines; ``#`` comments allowed).
        functions: functions the text may call (``inside(d1, pole1)``); none when omitted.

    Raises:
        SpecError: any syntax error, with ``line``, ``column``, ``token`` and ``expected``.
    """
    if not isinstance(text, str):
        raise TypeError(f"spec text must be a str, got {type(text).__name__}")
    parser = _Parser(text, functions)
    try:
        return parser.spec()
    except RecursionError:
        raise parser.error(
            "less deeply nested text", message="formula nested too deeply to parse"
        ) from None
