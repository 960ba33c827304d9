"""Scalar expressions of scene files: parsed into a small tree, evaluated and differentiated — never eval-ed.

Grammar: numbers, names (parameters, `t`, `pi`, `e`), calls of the functions in FUNCTIONS,
`+ - * / ^ **` (power right-associative, binds tighter than unary minus) and parentheses.
"""

import functools
import math
import re

FUNCTIONS = {
    "sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": math.asin, "acos": math.acos,
    "atan": math.atan, "atan2": math.atan2, "sinh": math.sinh, "cosh": math.cosh, "tanh": math.tanh,
    "exp": math.exp, "log": math.log, "sqrt": math.sqrt, "abs": abs, "min": min, "max": max,
}
ARITY = {"atan2": 2, "min": None, "max": None}  # None: two or more
CONSTANTS = {"pi": math.pi}

_TOKEN = re.compile(r"\s*(?:(\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)|([A-Za-z_][A-Za-z_0-9.]*)|(\*\*|[-+*/^(),]))")


class ExprError(ValueError):
    """A malformed expression; `pos` is the character offset."""

    def __init__(self, message, text, pos):
        super().__init__(f"{message} in expression '{text}' at column {pos + 1}")
        self.text, self.pos = text, pos


def _tokenize(text):
    pos, out = 0, []
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise ExprError(f"unexpected character '{text[pos:].strip()[:1]}'", text, pos)
        kind = "num" if m.group(1) else "name" if m.group(2) else "op"
        out.append((kind, m.group(m.lastindex), m.start(m.lastindex)))
        pos = m.end()
    out.append(("end", "", len(text)))
    return out


class _Parser:
    """Recursive descent: expr := term (('+'|'-') term)*; term := unary (('*'|'/') unary)*;
    unary := '-' unary | power; power := atom (('^'|'**') unary)?"""

    def __init__(self, text):
        self.text, self.tokens, self.i = text, _tokenize(text), 0

    def peek(self):
        return self.tokens[self.i]

    def take(self, value=None):
        tok = self.tokens[self.i]
        if value is not None and tok[1] != value:
            raise ExprError(f"expected '{value}'" + (f" but found '{tok[1]}'" if tok[1] else " but the expression ended"), self.text, tok[2])
        self.i += 1
        return tok

    def parse(self):
        node = self.expr()
        tok = self.peek()
        if tok[0] != "end":
            raise ExprError(f"unexpected '{tok[1]}'", self.text, tok[2])
        return node

    def expr(self):
        node = self.term()
        while self.peek()[1] in ("+", "-"):
            op = self.take()[1]
            node = (op, node, self.term())
        return node

    def term(self):
        node = self.unary()
        while self.peek()[1] in ("*", "/"):
            op = self.take()[1]
            node = (op, node, self.unary())
        return node

    def unary(self):
        if self.peek()[1] == "-":
            self.take()
            return ("neg", self.unary())
        if self.peek()[1] == "+":
            self.take()
            return self.unary()
        return self.power()

    def power(self):
        node = self.atom()
        if self.peek()[1] in ("^", "**"):
            self.take()
            node = ("^", node, self.unary())
        return node

    def atom(self):
        kind, value, pos = self.take()
        if kind == "num":
            return ("num", float(value))
        if kind == "name":
            if self.peek()[1] == "(":
                if value not in FUNCTIONS:
                    raise ExprError(f"unknown function '{value}' (valid: {', '.join(FUNCTIONS)})", self.text, pos)
                self.take("(")
                args = [self.expr()]
                while self.peek()[1] == ",":
                    self.take()
                    args.append(self.expr())
                self.take(")")
                n = ARITY.get(value, 1)
                if (n is None and len(args) < 2) or (n is not None and len(args) != n):
                    raise ExprError(f"'{value}' takes {'two or more' if n is None else n} argument(s), got {len(args)}", self.text, pos)
                return ("call", value, tuple(args))
            if value in CONSTANTS:
                return ("num", CONSTANTS[value])
            return ("name", value)
        if value == "(":
            node = self.expr()
            self.take(")")
            return node
        raise ExprError("expected a number, name or '('" + (f" but found '{value}'" if value else " but the expression ended"), self.text, pos)


class Expr:
    """A parsed expression: `names` are its free variables; `__call__(env)` evaluates it."""

    __slots__ = ("text", "tree", "names", "_fn")

    def __init__(self, text, tree=None):
        self.text = str(text)
        try:
            self.tree = tree if tree is not None else _Parser(self.text).parse()
            self.names = frozenset(_names(self.tree))
            self._fn = _compile(self.tree)
        except RecursionError:
            raise ExprError("the expression is nested too deeply", self.text, 0) from None

    def __call__(self, env):
        return float(self._fn(env))

    @property
    def is_constant(self):
        return not self.names

    def diff(self, var):
        """d(self)/d(var) as a new Expr."""
        tree = _simplify(_diff(self.tree, var))
        return Expr(_to_text(tree), tree)

    def __repr__(self):
        return f"Expr({self.text!r})"


def parse(value):
    """A number or a string → Expr (numbers become constants)."""
    if isinstance(value, Expr):
        return value
    if isinstance(value, bool):
        raise ExprError("expected a number, got a boolean", str(value), 0)
    if isinstance(value, (int, float)):
        return _parsed(repr(float(value)), True)
    if isinstance(value, str):
        return _parsed(value, False)
    raise ExprError(f"expected a number or an expression string, got {type(value).__name__}", str(value), 0)


@functools.lru_cache(maxsize=4096)
def _parsed(text, number):
    """An Expr is immutable, so one per text serves every field that writes it (a 10,000-body scene writes 0,
    1.0 and a few expressions 300,000 times); failures are not cached (they raise)."""
    return Expr(text, ("num", float(text))) if number else Expr(text)


def _names(node):
    kind = node[0]
    if kind == "name":
        yield node[1]
    elif kind in ("call", "sel"):
        for a in node[2] if kind == "call" else node[2:]:
            yield from _names(a)
    elif kind != "num":
        for a in node[1:]:
            yield from _names(a)


_BINARY = {"+": lambda a, b: a + b, "-": lambda a, b: a - b, "*": lambda a, b: a * b,
           "/": lambda a, b: a / b, "^": lambda a, b: a ** b}


def _compile(node):
    """Tree → closure env -> float (built once, so evaluation does no parsing)."""
    kind = node[0]
    if kind == "num":
        v = node[1]
        return lambda env: v
    if kind == "name":
        name = node[1]
        return lambda env: env[name]
    if kind == "neg":
        f = _compile(node[1])
        return lambda env: -f(env)
    if kind == "sel":  # piecewise: the derivative of the active branch of min/max (see _diff)
        fa, fb, fx, fy = (_compile(a) for a in node[2:])
        sign = 1.0 if node[1] == "min" else -1.0

        def select(env):
            d = sign * (fa(env) - fb(env))
            return fx(env) if d < 0 else fy(env) if d > 0 else 0.5 * (fx(env) + fy(env))
        return select
    if kind == "call":
        fn, args = FUNCTIONS[node[1]], [_compile(a) for a in node[2]]
        if len(args) == 1:
            a0 = args[0]
            return lambda env: fn(a0(env))
        return lambda env: fn(*[a(env) for a in args])
    op, fa, fb = _BINARY[kind], _compile(node[1]), _compile(node[2])
    return lambda env: op(fa(env), fb(env))


def _diff(n, v):
    """Symbolic derivative of a tree (chain rule per node kind)."""
    k = n[0]
    if k == "num":
        return ("num", 0.0)
    if k == "name":
        return ("num", 1.0 if n[1] == v else 0.0)
    if k == "neg":
        return ("neg", _diff(n[1], v))
    if k in "+-":
        return (k, _diff(n[1], v), _diff(n[2], v))
    if k == "*":
        a, b = n[1], n[2]
        return ("+", ("*", _diff(a, v), b), ("*", a, _diff(b, v)))
    if k == "/":
        a, b = n[1], n[2]
        return ("/", ("-", ("*", _diff(a, v), b), ("*", a, _diff(b, v))), ("^", b, ("num", 2.0)))
    if k == "^":
        a, b = n[1], n[2]
        if v not in set(_names(b)):  # d(a^c) = c a^(c-1) a'
            return ("*", ("*", b, ("^", a, ("-", b, ("num", 1.0)))), _diff(a, v))
        return ("*", n, ("+", ("*", _diff(b, v), ("call", "log", (a,))), ("/", ("*", b, _diff(a, v)), a)))
    if k == "sel":  # d/dv of the selected branch; the selection itself is piecewise constant
        return ("sel", n[1], n[2], n[3], _diff(n[4], v), _diff(n[5], v))
    name, args = n[1], n[2]
    if name in ("min", "max"):
        # min(a, b, c) = min(min(a, b), c); d min(a, b) = a' where a < b, b' where a > b (a piecewise
        # node, selected at evaluation time); at an exact tie the mean of the two one-sided
        # derivatives, so that C¹ joins such as f(min(t, T)) + c·max(t − T, 0) stay exact there
        # (second derivatives at a tie are exact only where the joined branches have zero curvature)
        a = args[0]
        for b in args[1:]:
            node = ("call", name, (a, b))
            d = ("sel", name, a, b, _diff(a, v), _diff(b, v))
            a = node
        return d
    a = args[0]
    da = _diff(a, v)
    outer = {
        "sin": ("call", "cos", (a,)),
        "cos": ("neg", ("call", "sin", (a,))),
        "tan": ("+", ("num", 1.0), ("^", ("call", "tan", (a,)), ("num", 2.0))),
        "asin": ("/", ("num", 1.0), ("call", "sqrt", (("-", ("num", 1.0), ("^", a, ("num", 2.0))),))),
        "acos": ("neg", ("/", ("num", 1.0), ("call", "sqrt", (("-", ("num", 1.0), ("^", a, ("num", 2.0))),)))),
        "atan": ("/", ("num", 1.0), ("+", ("num", 1.0), ("^", a, ("num", 2.0)))),
        "sinh": ("call", "cosh", (a,)),
        "cosh": ("call", "sinh", (a,)),
        "tanh": ("-", ("num", 1.0), ("^", ("call", "tanh", (a,)), ("num", 2.0))),
        "exp": ("call", "exp", (a,)),
        "log": ("/", ("num", 1.0), a),
        "sqrt": ("/", ("num", 0.5), ("call", "sqrt", (a,))),
        "abs": ("/", a, ("call", "abs", (a,))),
    }
    if name == "atan2":  # d atan2(a, b) = (b a' - a b') / (a^2 + b^2)
        b = args[1]
        return ("/", ("-", ("*", b, da), ("*", a, _diff(b, v))), ("+", ("^", a, ("num", 2.0)), ("^", b, ("num", 2.0))))
    return ("*", outer[name], da)


def _simplify(n):
    """Fold constants and drop zeros/ones so derivatives stay small."""
    k = n[0]
    if k in ("num", "name"):
        return n
    if k == "neg":
        a = _simplify(n[1])
        return ("num", -a[1]) if a[0] == "num" else ("neg", a)
    if k == "sel":
        a, b, x, y = (_simplify(m) for m in n[2:])
        if x == y:
            return x
        if a[0] == "num" and b[0] == "num" and a != b:
            return x if (a[1] < b[1]) == (n[1] == "min") else y
        return ("sel", n[1], a, b, x, y)
    if k == "call":
        args = tuple(_simplify(a) for a in n[2])
        if all(a[0] == "num" for a in args):
            return ("num", float(FUNCTIONS[n[1]](*[a[1] for a in args])))
        return ("call", n[1], args)
    a, b = _simplify(n[1]), _simplify(n[2])
    if a[0] == "num" and b[0] == "num":
        return ("num", float(_BINARY[k](a[1], b[1])))
    za, zb = a == ("num", 0.0), b == ("num", 0.0)
    oa, ob = a == ("num", 1.0), b == ("num", 1.0)
    if k == "+":
        return b if za else a if zb else (k, a, b)
    if k == "-":
        return ("neg", b) if za else a if zb else (k, a, b)
    if k == "*":
        return ("num", 0.0) if (za or zb) else b if oa else a if ob else (k, a, b)
    if k == "/":
        return ("num", 0.0) if za else a if ob else (k, a, b)
    if k == "^":
        return ("num", 1.0) if zb else a if ob else (k, a, b)
    return (k, a, b)


def _to_text(n):
    k = n[0]
    if k == "num":
        return repr(n[1])
    if k == "name":
        return n[1]
    if k == "neg":
        return f"(-{_to_text(n[1])})"
    if k == "call":
        return f"{n[1]}({', '.join(_to_text(a) for a in n[2])})"
    if k == "sel":  # display only (never re-parsed: Expr.diff keeps the tree)
        rel = "<" if n[1] == "min" else ">"
        return f"({_to_text(n[4])} if {_to_text(n[2])} {rel} {_to_text(n[3])} else {_to_text(n[5])})"
    return f"({_to_text(n[1])} {k} {_to_text(n[2])})"
