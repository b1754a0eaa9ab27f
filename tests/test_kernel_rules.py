"""The compiled core's ground rules, held by reading its source (agents/kernels/__init__.py):
written-order scalar arithmetic only, so compiled == interpreted and batch of one == whole team."""

import io
import re
import tokenize
from pathlib import Path

import pytest

KERNELS = Path(__file__).resolve().parents[1] / "agents" / "kernels"

# each pattern reorders or replaces the written arithmetic (BLAS products, LAPACK, reassociation,
# threads) or is not CPython's algorithm (math.hypot: CPython's own; numba lowers it to libm's)
FORBIDDEN = {
    r"\bnp\.dot\b|\bnumpy\.dot\b": "np.dot (BLAS)",
    r"\bnp\.linalg\b|\bnumpy\.linalg\b": "np.linalg (LAPACK)",
    r"\bfastmath\b": "fastmath (reorders sums)",
    r"\bparallel\b": "parallel (reorders reductions)",
    r"\bprange\b": "prange (threads)",
    r"\bmath\.hypot\b": "math.hypot (CPython's own algorithm; write abs(complex(x, y)))",
    r"\bnp\.hypot\b": "np.hypot",
}
MATMUL = "the matmul operator (BLAS)"


def violations(text: str) -> list[tuple[int, str]]:
    """(line, rule) for every forbidden construct in the code of ``text`` (strings and comments aside)."""
    code: dict[int, list[str]] = {}
    found = []
    first_on_line = True
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in (tokenize.NEWLINE, tokenize.NL):
            first_on_line = True
            continue
        if tok.type in (tokenize.INDENT, tokenize.DEDENT, tokenize.COMMENT, tokenize.STRING):
            continue
        if tok.type == tokenize.OP and tok.string in ("@", "@=") and not first_on_line:
            found.append((tok.start[0], MATMUL))  # a leading '@' is a decorator
        code.setdefault(tok.start[0], []).append(tok.string)
        first_on_line = False
    for line, toks in code.items():
        joined = "".join(toks)
        found += [(line, why) for pat, why in FORBIDDEN.items() if re.search(pat, joined)]
    return sorted(found)


@pytest.mark.parametrize("path", sorted(KERNELS.glob("*.py")), ids=lambda p: p.name)
def test_kernel_modules_keep_to_written_order_scalar_arithmetic(path):
    found = violations(path.read_text(encoding="utf-8"))
    assert not found, "\n".join(f"{path.name}:{line}: {why}" for line, why in found)


def test_the_rules_catch_what_they_forbid_and_nothing_in_strings_or_decorators():
    bad = ('x = a @ b\ny = np.linalg.solve(a, b)\nz = math.hypot(u, v)\n@jit\ndef f():\n'
           '    """np.dot in a docstring, a @ b"""\n    return 0  # fastmath in a comment\n')
    assert violations(bad) == [(1, MATMUL), (2, "np.linalg (LAPACK)"),
                               (3, "math.hypot (CPython's own algorithm; write abs(complex(x, y)))")]


def test_warm_runs_every_registered_warmer():
    from agents import kernels

    calls = []
    kernels.register_warm(lambda: calls.append(1))
    try:
        kernels.warm()
    finally:
        kernels._WARMERS.pop()
    assert calls == [1]
