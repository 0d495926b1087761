"""A faster state derivative, compiled from the model's own generated code, same numbers.

hostsim.model.equations generates ``mass_matrix_forcing(q, qd, u, p)`` (flat M and F) and hostsim.world.plant
solves ``M q'' = F`` with a pure-Python Cholesky (``solve_spd5``). The simulator evaluates
that four times per millisecond, so it dominates every firmware-in-the-loop run. This
module rewrites the generated function (with ``ast``, no sympy) into

- ``prepare(p)``: every subexpression that depends on the parameters only, computed once
  per model (they are most of the constants: masses times lengths squared, ...);
- ``deriv(x, u, pre)``: the rest of M (its lower triangle only: the Cholesky never reads the
  upper one) and F, then the Cholesky factorization and both triangular solves unrolled
  into straight-line code over local variables, returning ``[q', q'']`` as a list;
- ``deriv_ext(x, u, pre, e, rhs)``: the same with additions to M and F (``e``: the 15 entries
  of M's lower triangle, row by row, then the 5 of F) and, after ``[q', q'']``, the solutions
  M^-1 r of each extra right-hand side r in ``rhs`` (hostsim.world.drivetrain: a rotor taken
  out of the mass matrix or locked by friction).

Every floating-point operation is the one the original code performs, in the same order
(hoisted subtrees are whole nodes of the original expression trees, the unrolled solve
repeats solve_spd5's loop order), so the result is bit-for-bit that of
``qd + solve_spd5(*mass_matrix_forcing(...))``; tests/test_sim_plant.py checks it.
"""
import ast
import math

N_Q = 5


class _Names(ast.NodeVisitor):
    def __init__(self):
        self.names = set()

    def visit_Name(self, node):
        self.names.add(node.id)


def _names(node):
    v = _Names()
    v.visit(node)
    return v.names


def _unpacked(stmt):
    """Names of a ``a, b, c, = seq`` statement."""
    return [e.id for e in stmt.targets[0].elts]


class _Hoister(ast.NodeTransformer):
    """Replace maximal parameter-only subtrees of an expression by new hoisted names."""

    def __init__(self, is_const, new_name):
        self.is_const = is_const
        self.new_name = new_name

    def generic_visit(self, node):
        if isinstance(node, ast.expr) and not isinstance(node, (ast.Name, ast.Constant)) and self.is_const(node):
            return ast.Name(id=self.new_name(node), ctx=ast.Load())
        return super().generic_visit(node)


def _function(module_source, name):
    tree = ast.parse(module_source)
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return node
    raise ValueError("generated model code has no function %r" % name)


def compile_source(module_source):
    """Python source of ``prepare`` and ``deriv`` from the model's generated module source."""
    fn = _function(module_source, "mass_matrix_forcing")
    body = fn.body
    q_names, qd_names, u_names, p_names = (_unpacked(s) for s in body[:4])
    assigns, ret = body[4:-1], body[-1]
    if not isinstance(ret, ast.Return) or len(ret.value.elts) != N_Q * N_Q + N_Q:
        raise ValueError("unexpected shape of the generated mass_matrix_forcing")
    variable = set(q_names) | set(qd_names) | set(u_names)
    const = set(p_names)       # names known at prepare() time
    hoisted = []               # (name, expression source) in evaluation order

    def is_const(node):
        used = _names(node)
        # Names that are neither assigned here nor arguments are the math module's globals.
        return not (used & variable)

    counter = [0]

    def new_name(node):
        counter[0] += 1
        name = "h%d" % counter[0]
        hoisted.append((name, ast.unparse(node)))
        return name

    hoister = _Hoister(is_const, new_name)
    kept = []
    for stmt in assigns:
        target = stmt.targets[0].id
        if is_const(stmt.value):
            hoisted.append((target, ast.unparse(stmt.value)))
            const.add(target)
        else:
            kept.append((target, hoister.visit(stmt.value)))
            variable.add(target)
    outputs = [hoister.visit(e) for e in ret.value.elts]
    m_out = {(i, j): outputs[i * N_Q + j] for i in range(N_Q) for j in range(i + 1)}
    f_out = outputs[N_Q * N_Q:]

    # Drop the assignments only the upper triangle of M needed.
    needed = set()
    for e in list(m_out.values()) + f_out:
        needed |= _names(e)
    live = []
    for target, value in reversed(kept):
        if target in needed:
            live.append((target, value))
            needed |= _names(value)
    live.reverse()
    used = set()
    for _, v in live:
        used |= _names(v)
    for e in list(m_out.values()) + f_out:
        used |= _names(e)
    # deriv() gets the hoisted values and the raw parameters its remaining code still reads.
    passed = [n for n, _ in hoisted] + [n for n in p_names if n in used]

    lines = ["def prepare(p):"]
    lines.append("    %s, = p" % ", ".join(p_names))
    lines += ["    %s = %s" % (n, src) for n, src in hoisted]
    lines.append("    return (%s,)" % ", ".join(passed))
    lines.append("")
    head = ["    %s, = x" % ", ".join(q_names + qd_names),
            "    %s = u[0], u[1], u[3], u[4]" % ", ".join(u_names),
            "    %s, = pre" % ", ".join(passed)]
    head += ["    %s = %s" % (t, ast.unparse(v)) for t, v in live]
    m_lines = ["    m%d%d = %s" % (i, j, ast.unparse(e)) for (i, j), e in m_out.items()]
    f_lines = ["    f%d = %s" % (i, ast.unparse(e)) for i, e in enumerate(f_out)]
    chol = _cholesky_lines(qd_names)
    lines += ["def deriv(x, u, pre):"] + head + m_lines + f_lines + chol
    # deriv_ext: the same code with the additions e to M and F, and the extra right-hand sides.
    lines += ["", "def deriv_ext(x, u, pre, e, rhs):"] + head
    lines += ["    m%d%d = (%s) + e[%d]" % (i, j, ast.unparse(e), k) for k, ((i, j), e) in enumerate(m_out.items())]
    lines += ["    f%d = (%s) + e[%d]" % (i, ast.unparse(e), len(m_out) + i) for i, e in enumerate(f_out)]
    lines += chol[:-1] + ["    out = " + chol[-1].strip()[len("return "):]] + _extra_solve_lines()
    lines.append("    return out")
    return "\n".join(lines) + "\n"


def _extra_solve_lines():
    """The triangular solves of _cholesky_lines again, for each r in rhs."""
    return (["    for r in rhs:"] + _solve_lines("r[%d]", "z", "s", "        ")
            + ["        out += [%s]" % ", ".join("s%d" % i for i in range(N_Q))])


def _solve_lines(rhs, y, x, indent):
    """L y = rhs, then L^T x = y, with the factor l<i><j> of _cholesky_lines (rhs: a format of
    the entry's index; y, x: prefixes of the locals)."""
    n = N_Q
    out = []
    for i in range(n):
        terms = "".join(" - l%d%d * %s%d" % (i, k, y, k) for k in range(i))
        out.append("%s%s%d = (%s%s) / l%d%d" % (indent, y, i, rhs % i, terms, i, i))
    for i in range(n - 1, -1, -1):
        terms = "".join(" - l%d%d * %s%d" % (k, i, x, k) for k in range(i + 1, n))
        out.append("%s%s%d = (%s%d%s) / l%d%d" % (indent, x, i, y, i, terms, i, i))
    return out


def _cholesky_lines(qd_names):
    """solve_spd5 unrolled: the same operations in the same order, on locals."""
    n = N_Q
    out = []
    for i in range(n):
        for j in range(i + 1):
            terms = "".join(" - l%d%d * l%d%d" % (i, k, j, k) for k in range(j))
            if i == j:
                out.append("    s = m%d%d%s" % (i, j, terms))
                out.append("    if s <= 0.0:")
                out.append("        raise _not_spd()")
                out.append("    l%d%d = sqrt(s)" % (i, i))
            else:
                out.append("    l%d%d = (m%d%d%s) / l%d%d" % (i, j, i, j, terms, j, j))
    out += _solve_lines("f%d", "y", "a", "    ")
    out.append("    return [%s, %s]" % (", ".join(qd_names), ", ".join("a%d" % i for i in range(n))))
    return out


def _not_spd():
    import numpy as np
    return np.linalg.LinAlgError("mass matrix is not positive definite")


_CACHE = {}


def compile_model(model):
    """(deriv, pre) for a hostsim.model.RobotModel: deriv(x, u, pre) -> [q', q''] (lists)."""
    path = model._f.__file__
    fns = _CACHE.get(path)
    if fns is None:
        with open(path) as f:
            source = compile_source(f.read())
        namespace = {"_not_spd": _not_spd}
        namespace.update({k: getattr(math, k) for k in dir(math) if not k.startswith("_")})
        exec(compile(source, "<hostsim.model.fastdyn %s>" % path, "exec"), namespace)
        fns = _CACHE[path] = (namespace["prepare"], namespace["deriv"], namespace["deriv_ext"])
    return fns[1], fns[0](model._pl)


def compile_model_ext(model):
    """(deriv_ext, pre) for a hostsim.model.RobotModel (see the module docstring)."""
    compile_model(model)
    fns = _CACHE[model._f.__file__]
    return fns[2], fns[0](model._pl)
