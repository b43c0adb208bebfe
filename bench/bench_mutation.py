"""Mutation testing of the safety and durability code: do its tests bite?

An own runner (``ast``, standard library): mutmut and cosmic-ray rewrite files in the tree
and rerun whole suites, far too slow for this machine's two shared cores. Each mutant is one
one-line change of the module's source:

* ``delete``: a statement replaced by ``pass`` (a dropped ``os.fsync``, ``stop_now()``,
  check call, ``raise``, assignment);
* ``compare``: a comparison flipped at its boundary (``<`` / ``<=``, ``>`` / ``>=``,
  ``==`` / ``!=``, ``is`` / ``is not``, ``in`` / ``not in``);
* ``negate``: an ``if`` / ``while`` condition negated;
* ``boolop``: ``and`` / ``or`` swapped;
* ``call``: ``os.link`` -> ``os.replace`` (the never-overwrite guard), ``abs(x)`` /
  ``np.abs(x)`` -> ``x`` (a check on the positive half only), ``p.with_name(...)`` -> ``p``
  (a temp file beside the target becomes the target: written in place),
  ``np.array_equal(...)`` -> ``True`` (a comparison skipped);
* ``constant``: a number changed (``0`` -> ``1``, ``n`` -> ``n + 1``, ``x`` -> ``2 x``).

Each mutant runs in a fresh interpreter: the mutated source is compiled under the module's
own file name and put into ``sys.modules`` before pytest imports anything, so the tree is
never written (a kill of the bench leaves no mutant behind); then the module's relevant
test files run (``-x``, a timeout of 3x the clean run + 20 s). A mutant is *killed* when
the tests fail or time out, *survives* when they pass. Tests that start other processes
(``test_kill``, ``test_store_processes``) cannot see an in-memory mutant and are not used.

The named survivors (issue 29's and those of later runs, :data:`NAMED`) are always run;
the other mutants are a seeded sample per module (``--per-module``, default 12; ``--all``
runs every one). Mutants no behaviour can tell apart (:data:`EQUIVALENT`, each with its
reason) are listed, not run. Two mutants run at once (``--jobs``). Survival per module as
``k/n = rate`` with its Wilson 95 % interval, against the target of at most 10 %; a missed
target is printed "missed". The baseline is no tests at all (100 % survive).

    python bench/bench_mutation.py                 # named + 12 sampled per module
    python bench/bench_mutation.py --per-module 0  # the named survivors only
    python bench/bench_mutation.py --all rig/safety.py
"""

from __future__ import annotations

import argparse
import ast
import math
import os
import random
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_SURVIVAL = 0.10

#: module file -> the test files that exercise it in-process (the bite tests first: with
#: ``-x`` a mutant they kill is over in seconds)
MODULES: dict[str, list[str]] = {
    "rig/safety.py": ["tests/rig/test_safety_bite.py", "tests/rig/test_safety.py"],
    "drivers/stg_waveform.py": ["tests/drivers/test_stg_waveform_bite.py",
                                "tests/drivers/test_stg_charge_balance.py",
                                "tests/drivers/test_stg4002.py"],
    "drivers/stg_download.py": ["tests/drivers/test_stg_download_bite.py",
                                "tests/drivers/test_stg_waveform_bite.py",
                                "tests/drivers/test_stg_charge_balance.py"],
    "protocols/session_publish.py": ["tests/protocols/test_session_publish_bite.py",
                                     "tests/rig/test_store_bite.py",
                                     "tests/rig/test_recovery_bite.py",
                                     "tests/protocols/test_session_publish.py",
                                     "tests/rig/test_session_store.py",
                                     "tests/rig/test_store_windows.py"],
    "rig/journal.py": ["tests/rig/test_journal_bite.py", "tests/rig/test_store_bite.py",
                       "tests/rig/test_recovery_bite.py", "tests/rig/test_session_log.py",
                       "tests/rig/test_store_windows.py", "tests/rig/test_store_merge.py",
                       "tests/rig/test_session_speed.py"],
    "rig/recovery.py": ["tests/rig/test_recovery_bite.py", "tests/rig/test_store_bite.py",
                        "tests/rig/test_session_log.py", "tests/rig/test_session_store.py",
                        "tests/rig/test_store_merge.py", "tests/rig/test_store_windows.py"],
}

#: The named survivors of issue 29 and of the bench's later runs on main: (module, function,
#: kind, text the mutated line holds); ``kind#n`` is the n-th such mutant. Matched by
#: behaviour's location, not line numbers (the store is being rewritten). Each is killed
#: by a test of the behaviour named beside it.
NAMED: list[tuple[str, str, str, str]] = [
    # the first stop_now() of a trip (output stops late while start() blocks)
    ("rig/safety.py", "trip", "delete#1", "self._stop_output()"),
    # the E-stop rule's status without a trip (switch watched or not)
    ("rig/safety.py", "__init__", "delete", 'self.detail = "ok (switch released)"'),
    # an E-stop logged as INFO, a fault trip as WARNING
    ("rig/safety.py", "trip", "compare", "logging.INFO if rule =="),
    # the charge balance checked before a download
    ("drivers/stg_download.py", "prepare_download", "delete", "check_charge_balance("),
    # the rendered ceiling checked on both halves of the carrier
    ("drivers/stg_waveform.py", "check_rendered", "call", "np.abs(values)"),
    # (the empty-envelope return of period_amplitudes_mA was equivalent: removed)
    # fsync before publishing; never overwrite a new file
    ("protocols/session_publish.py", "publish_image", "delete", "os.fsync("),
    ("protocols/session_publish.py", "_publish_new", "call", "os.link("),
    # a disk with exactly the space needed is enough
    ("protocols/session_publish.py", "publish_image", "compare", "if free < need"),
    # a failed write closes its temp file
    ("protocols/session_publish.py", "_discard", "delete", "os.close(fd)"),
    # journal entries fsynced, written aside then renamed
    ("rig/journal.py", "write_durable", "delete", "os.fsync("),
    ("rig/journal.py", "write_durable", "call", "with_name("),
    # an A/D wrench / sync journaled as counts
    ("rig/journal.py", "trial_members", "compare", 'if k in ("wrench", "sync")'),
    # a torn or foreign partial.json not streamed into
    ("rig/journal.py", "read_journal", "delete", "if pmeta is not None and not"),
    ("rig/journal.py", "read_journal", "boolop#2", "if pmeta is not None and not"),
    # recovery compares samples, not only positions
    ("rig/recovery.py", "_identity", "delete", "trial_digest("),
    # the damaged file kept aside where the volume has no hard links
    ("rig/recovery.py", "_keep_aside", "delete", "rename_retrying(path, aside)"),
    # two trials with the same samples at two schedule positions
    ("rig/recovery.py", "_identity", "boolop", "extra_attrs or {}"),
    # journal entries already in place are not rewritten
    ("rig/recovery.py", "_journal_as", "delete", "continue"),
]

#: Mutants no observable behaviour can tell from the module (module, function, kind, text,
#: why): not run, not counted. Where the equivalent line could go, it went instead (see
#: the module's history); what is left here is kept for the reason given.
EQUIVALENT: list[tuple[str, str, str, str, str]] = [
    ("rig/safety.py", "__init__", "delete", "self.switch_pressed = False",
     "EStopRule.switch_pressed is written in three places and read nowhere in the tree (the "
     "status, the trip and the re-arm use the rule's ok / detail and the switch itself)"),
    ("rig/safety.py", "check", "delete", "self.switch_pressed = True",
     "EStopRule.switch_pressed is read nowhere (see above)"),
    ("rig/safety.py", "check_switch", "delete", "self.estop_rule.switch_pressed = True",
     "EStopRule.switch_pressed is read nowhere (see above)"),
    ("drivers/stg_download.py", "save_stop_marks", "constant", "if P <= 0 or not len(",
     "P <= 0 -> P <= 1: a one-tick period has only its first tick, which is never marked, "
     "so skipping the channel marks the same nothing"),
    ("drivers/stg_download.py", "save_stop_marks", "constant",
     "np.where(mark, SYNC_SAVE_STOP, 0)",
     "0 -> 1 on unmarked ticks: bit 0 (SYNC_HIGH) is already set on every tick of ``out``"),
]


@dataclass
class Mutant:
    module: str
    index: int
    kind: str
    line: int
    function: str
    before: str
    after: str
    named: bool = False
    equivalent: str = ""

    def label(self) -> str:
        return f"{self.module}:{self.line} {self.kind} in {self.function or '<module>'}: " \
               f"{self.before.strip()[:60]!r} -> {self.after.strip()[:40]!r}"


_FLIP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt,
         ast.Eq: ast.NotEq, ast.NotEq: ast.Eq, ast.Is: ast.IsNot, ast.IsNot: ast.Is,
         ast.In: ast.NotIn, ast.NotIn: ast.In}


def _is_docstring(node, parent) -> bool:
    return (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str))


class _Sites(ast.NodeVisitor):
    """Every mutation site of a module, in a fixed order: (kind, node, function)."""

    def __init__(self):
        self.sites: list[tuple[str, ast.AST, str]] = []
        self.func: list[str] = []
        self._skip_const: set[int] = set()

    def visit_FunctionDef(self, node):
        self.func.append(node.name)
        for d in node.decorator_list:          # decorators and defaults are not logic
            self._mark_consts(d)
        for d in node.args.defaults + node.args.kw_defaults:
            if d is not None:
                self._mark_consts(d)
        self.generic_visit(node)
        self.func.pop()

    visit_AsyncFunctionDef = visit_FunctionDef

    def _mark_consts(self, node):
        for n in ast.walk(node):
            if isinstance(n, ast.Constant):
                self._skip_const.add(id(n))

    def _here(self) -> str:
        return ".".join(self.func)

    def generic_visit(self, node):
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            for stmt in body if isinstance(body, list) else []:
                if isinstance(stmt, ast.stmt) and self.func and not _is_docstring(stmt, node) \
                        and not isinstance(stmt, (ast.FunctionDef, ast.ClassDef, ast.Pass,
                                                  ast.AsyncFunctionDef)):
                    self.sites.append(("delete", stmt, self._here()))
        if self.func:
            if isinstance(node, ast.Compare) and type(node.ops[0]) in _FLIP:
                self.sites.append(("compare", node, self._here()))
            elif isinstance(node, (ast.If, ast.While)):
                self.sites.append(("negate", node, self._here()))
            elif isinstance(node, ast.BoolOp):
                self.sites.append(("boolop", node, self._here()))
            elif isinstance(node, ast.Call) and _call_swap(node) is not None:
                self.sites.append(("call", node, self._here()))
            elif isinstance(node, ast.Constant) and id(node) not in self._skip_const and \
                    type(node.value) in (int, float) and not isinstance(node.value, bool):
                self.sites.append(("constant", node, self._here()))
        if isinstance(node, ast.Constant):
            return
        super().generic_visit(node)


def _call_swap(node: ast.Call):
    """What a call is replaced with: ``os.link`` -> ``os.replace``, ``abs(x)`` -> ``x``."""
    f = node.func
    if isinstance(f, ast.Attribute) and f.attr == "link" and \
            isinstance(f.value, ast.Name) and f.value.id == "os":
        return ast.Call(func=ast.Attribute(value=ast.Name("os", ast.Load()), attr="replace",
                                           ctx=ast.Load()), args=node.args,
                        keywords=node.keywords)
    name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
    if name in ("abs", "fabs") and len(node.args) == 1:
        return node.args[0]
    if name == "with_name" and isinstance(f, ast.Attribute):
        return f.value  # a temp name beside the target -> the target itself: in place
    if name in ("array_equal", "allclose", "array_equiv"):
        return ast.Constant(True)  # a comparison skipped
    return None


class _Apply(ast.NodeTransformer):
    """Apply the ``n``-th site's mutation."""

    def __init__(self, kind: str, target: ast.AST):
        self.kind, self.target = kind, target

    def visit(self, node):
        if node is self.target:
            return self._mutate(node)
        return super().visit(node)

    def _mutate(self, node):
        k = self.kind
        if k == "delete":
            return ast.copy_location(ast.Pass(), node)
        if k == "compare":
            node.ops = [_FLIP[type(node.ops[0])](), *node.ops[1:]]
            return node
        if k == "negate":
            node.test = ast.UnaryOp(op=ast.Not(), operand=node.test)
            return node
        if k == "boolop":
            node.op = ast.Or() if isinstance(node.op, ast.And) else ast.And()
            return node
        if k == "call":
            return ast.copy_location(_call_swap(node), node)
        if k == "constant":
            v = node.value
            node.value = 1 if v == 0 else (v + 1 if isinstance(v, int) else v * 2.0)
            return node
        raise ValueError(k)


def mutants(module: str) -> tuple[str, list[Mutant]]:
    """The module's source and its mutants (the named ones flagged)."""
    src = (ROOT / module).read_text(encoding="utf-8")
    lines = src.splitlines()
    tree = ast.parse(src)
    finder = _Sites()
    finder.visit(tree)
    out = []
    for i, (kind, node, func) in enumerate(finder.sites):
        line = getattr(node, "lineno", 0)
        before = lines[line - 1] if line else ""
        out.append(Mutant(module, i, kind, line, func, before, _mutated_line(src, i)))
    for mod, func, kind, text in NAMED:
        if mod != module:
            continue
        base, _, nth = kind.partition("#")
        hits = [m for m in out if m.kind == base and text in m.before
                and (not func or m.function.split(".")[-1] == func)]
        if hits:
            hits[int(nth) - 1 if nth else 0].named = True
    for mod, func, kind, text, why in EQUIVALENT:
        if mod != module:
            continue
        for m in out:
            if m.kind == kind and text in m.before and m.function.split(".")[-1] == func:
                m.equivalent = why
    return src, out


def _mutated_source(src: str, index: int) -> str:
    tree = ast.parse(src)
    finder = _Sites()
    finder.visit(tree)
    kind, node, _ = finder.sites[index]
    tree = _Apply(kind, node).visit(tree)
    ast.fix_missing_locations(tree)
    return ast.unparse(tree)


def _mutated_line(src: str, index: int) -> str:
    tree = ast.parse(src)
    finder = _Sites()
    finder.visit(tree)
    kind, node, _ = finder.sites[index]
    new = _Apply(kind, node).visit(node) if kind != "delete" else ast.Pass()
    try:
        return ast.unparse(new).splitlines()[0]
    except Exception:  # noqa: BLE001 - a label only
        return kind


_RUNNER = r"""
import importlib, importlib.util, sys
name, origin, mutant = sys.argv[1], sys.argv[2], sys.argv[3]
importlib.import_module(name.rpartition(".")[0])
spec = importlib.util.spec_from_file_location(name, origin)
mod = importlib.util.module_from_spec(spec)
sys.modules[name] = mod
with open(mutant, encoding="utf-8") as fh:
    code = compile(fh.read(), origin, "exec")
exec(code, mod.__dict__)
setattr(sys.modules[name.rpartition(".")[0]], name.rpartition(".")[2], mod)
import pytest
sys.exit(pytest.main(["-q", "-x", "-p", "no:cacheprovider", "-p", "no:randomly",
                      *sys.argv[4:]]))
"""


def _module_name(module: str) -> str:
    return "nmsid." + module[:-3].replace("/", ".")


def run_tests(module: str, source: str, tests: list[str], timeout_s: float) -> tuple[str, float]:
    """Run ``tests`` against ``source`` as ``module``: ("passed" | "failed" | "timeout", s)."""
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", OPENBLAS_NUM_THREADS="1",
               PYTHONDONTWRITEBYTECODE="1")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mutant.py"
        path.write_text(source, encoding="utf-8")
        t0 = time.monotonic()
        try:
            p = subprocess.run([sys.executable, "-c", _RUNNER, _module_name(module),
                                str(ROOT / module), str(path), *tests], cwd=ROOT, env=env,
                               capture_output=True, text=True, timeout=timeout_s,
                               check=False)
        except subprocess.TimeoutExpired:
            return "timeout", time.monotonic() - t0
        took = time.monotonic() - t0
    return ("passed" if p.returncode == 0 else "failed"), took


def wilson_95(k: int, n: int) -> tuple[float, float]:
    """Wilson score 95 % interval of a proportion ``k / n`` (Wilson 1927)."""
    if n == 0:
        return 0.0, 1.0
    z = 1.959963984540054
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("modules", nargs="*", default=list(MODULES))
    ap.add_argument("--per-module", type=int, default=12,
                    help="sampled mutants per module besides the named ones (default 12)")
    ap.add_argument("--all", action="store_true", help="every mutant of each module")
    ap.add_argument("--seed", type=int, default=29)
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="mutants run at once (default: 2, or 1 on one core)")
    args = ap.parse_args(argv if argv is not None else [])
    t_start = time.monotonic()
    rows = []
    survivors: list[Mutant] = []
    skipped: list[Mutant] = []
    plan: dict[str, tuple[list[str], str, list[Mutant]]] = {}
    for module in args.modules:
        tests = [t for t in MODULES[module] if (ROOT / t).exists()]
        src, all_mutants = mutants(module)
        plan[module] = tests, src, all_mutants

    def clean_run(module: str) -> tuple[str, float]:
        # the baseline is the module as the mutants are built (ast.unparse, no change): a
        # mutant is only ever killed by its mutation, never by the rebuilding
        tests, src, _ = plan[module]
        return run_tests(module, ast.unparse(ast.parse(src)), tests, 600)

    def one(job: tuple[str, Mutant, float]) -> tuple[str, Mutant, str]:
        module, m, timeout_s = job
        tests, src, _ = plan[module]
        try:
            source = _mutated_source(src, m.index)
        except Exception as exc:  # noqa: BLE001 - an unbuildable mutant is not counted
            return module, m, f"not built: {exc}"
        return module, m, run_tests(module, source, tests, timeout_s)[0]

    # every module's clean run, then every mutant of every module, ``--jobs`` at a time
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        base = dict(zip(plan, pool.map(clean_run, plan), strict=True))
        jobs: list[tuple[str, Mutant, float]] = []
        n_named: dict[str, int] = {}
        for module, (_tests, _src, all_mutants) in plan.items():
            clean, base_s = base[module]
            if clean != "passed":
                print(f"{module}: the clean tests do not pass ({clean}); skipped")
                continue
            skipped += [m for m in all_mutants if m.equivalent]
            live = [m for m in all_mutants if not m.equivalent]
            named = [m for m in live if m.named]
            rest = [m for m in live if not m.named]
            if not args.all:
                rest = random.Random(f"{args.seed}:{module}").sample(
                    rest, min(args.per_module, len(rest)))
            n_named[module] = len(named)
            jobs += [(module, m, 3 * base_s + 20)
                     for m in sorted(named + rest, key=lambda m: m.index)]
        tally = {module: [0, 0] for module in n_named}  # run, killed
        for module, m, verdict in pool.map(one, jobs):
            if verdict.startswith("not built"):
                print(f"  ({verdict}: {m.label()})")
                continue
            tally[module][0] += 1
            if verdict == "passed":
                survivors.append(m)
            else:
                tally[module][1] += 1
            if m.named:
                print(f"  named: {m.label()}: "
                      f"{'SURVIVED' if verdict == 'passed' else 'killed'} ({verdict})")
    for module, (n, killed) in tally.items():
        rows.append((module, len(plan[module][2]), n, killed, base[module][1],
                     n_named[module]))
    print(f"{'module':<30}{'sites':>6}{'run':>5}{'named':>6}{'survived':>14}"
          f"{'Wilson 95 %':>14}  target <= {TARGET_SURVIVAL:.0%} survive")
    for module, n_all, n, killed, base_s, named_n in rows:
        k = n - killed
        rate = k / n if n else 0.0
        lo, hi = wilson_95(k, n)
        verdict = "met" if rate <= TARGET_SURVIVAL else "missed"
        print(f"{module:<30}{n_all:>6}{n:>5}{named_n:>6}{f'{k}/{n} = {rate:.0%}':>14}"
              f"{f'{lo:.0%}-{hi:.0%}':>14}  {verdict} (clean tests {base_s:.1f} s)")
    tot_n = sum(r[2] for r in rows)
    tot_k = tot_n - sum(r[3] for r in rows)
    if tot_n:
        lo, hi = wilson_95(tot_k, tot_n)
        print(f"all: {tot_k}/{tot_n} = {tot_k / tot_n:.0%} survived (Wilson 95 % {lo:.0%}-"
              f"{hi:.0%}); the baseline, no tests at all, lets 100 % survive")
    for m in survivors:
        print(f"  survived: {m.label()}")
    for m in skipped:
        print(f"  equivalent, not run: {m.label()}: {m.equivalent}")
    print(f"bench wall time {time.monotonic() - t_start:.0f} s ({args.jobs} at once)")


if __name__ == "__main__":
    main(sys.argv[1:])
