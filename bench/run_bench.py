"""Benchmark of the KPI design (``make bench``): derivatives, solvers, growth with the number of poses.

Measured in one run on the kr16 problem of SPEC (default cell, q_work from the model file,
sigma = 1 mm, 27 parameters), and written as Markdown to ``bench/results.md`` (and stdout):

1. One evaluation of the KPI criterion tr(Cs)/3 and its gradient w.r.t. the 360 joint angles of a
   60-pose design (the heuristic design, seed 0), three ways:
   - closed form (what the optimiser uses): d F1/d q in closed form, adjoint gradient of tr(Cs);
   - forward finite differences of the closed-form value (361 value evaluations);
   - Drake AutoDiffXd: the same chain (forward kinematics, identification Jacobian columns,
     tracker rotation columns, F1^T F1, inverse, tr(Js M^-1 Js^T)/3) evaluated on numpy object
     arrays of AutoDiffXd with 360 derivatives; the 27x27 products and the inverse go through
     ``pydrake.math.matmul`` / ``pydrake.math.inv`` (C++), everything else is numpy on objects.
   All three are checked against each other before they are timed.
2. SNOPT vs IPOPT (and SNOPT given all clearance rows instead of each pose's smallest) on the KPI
   design with collision avoidance, 60 poses, several seeds: wall time of
   the solve, final tr(Cs)/3, evaluations; medians.
3. KPI design with collision avoidance for N = 15, 30, 60, 120, 240 poses: solve time and the
   exponent of a log-log fit t ~ N^p, for SNOPT as configured by default (block sweeps above 60
   poses), SNOPT in one solve over all poses, and IPOPT.

Wall times depend on the machine and on its load; CPU time of this process is reported beside them.

4. Calibration and diagnosis of 1000 poses (measured UR5 data and simulated kr16 data, sigma 0.02
   and 0.065 mm): wall time and peak memory of each ``kpioed`` command (``bench/fits_bench.py``).
5. Compensation of 1000 program rows with a calibrated kr16 model (``bench/compensate_bench.py``).
6. Diagnosis of 400 and 1000 poses of the 11-joint elastic humanoid stand-in whose model file has
   no masses (``bench/humanoid.py``): wall and CPU time, the causes named, their ratio.
7. One online step (``kpioed next``) at 100 measured kr16 poses (``bench/online_bench.py``).
8. The 18-joint two-arm twin: its 40-pose KPI design (cold and warm certificate cache, and without
   the certificate), a warm online step, three diagnoses of 400 poses: the two twin stand-ins and
   the two-arm diagnosis stand-in of issue 46 (``bench/twin_bench.py``).

Usage: ``python bench/run_bench.py [--seeds 5] [--sizes 15,30,60,120,240] [--out bench/results.md]``;
``--only fits|compensate|humanoid|online|twin`` runs section 4, 5, 6, 7 or 8 alone and replaces only
that section of the existing ``--out`` file.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import time
from pathlib import Path

# Small matrices: BLAS threads only add contention (set before numpy is imported).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import compensate_bench  # noqa: E402
import humanoid  # noqa: E402
import numpy as np  # noqa: E402
import online_bench  # noqa: E402
import twin_bench  # noqa: E402
from fits_bench import bench_fits, replace_section, section_lines, targets_lines, update_results  # noqa: E402

from kpioed_drake import design  # noqa: E402
from kpioed_drake.estimation.problem import Problem, make_problem  # noqa: E402
from kpioed_drake.outputs import atomic_write_text  # noqa: E402
from kpioed_drake.robot.models import N_JOINTS  # noqa: E402
from kpioed_drake.tracker.measurement import N_FULL  # noqa: E402


# ----------------------------------------------------------------------------------------------
# The KPI criterion written once for any scalar type (float or AutoDiffXd object arrays)
# ----------------------------------------------------------------------------------------------
def _rz(c, s):
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def generic_F1(problem: Problem, q: np.ndarray) -> np.ndarray:
    """F1 (3n, 27) of ``q`` (n, 6), float or AutoDiffXd objects; mirrors kinematics + measurement."""
    robot, model = problem.robot, problem.model
    g = model.geometry
    n = q.shape[0]
    dtype = q.dtype
    R = np.empty((n, 3, 3), dtype=dtype)
    R[:] = np.eye(3)
    o = np.zeros((n, 3), dtype=dtype)
    elems = []  # (u (n,3), o (n,3) or None for translations)
    for i, conv in enumerate(robot.conventions):
        ang = g[i, 0] + q[:, i]
        RA = R @ _rz(np.cos(ang), np.sin(ang))
        xA, zp = RA[:, :, 0], R[:, :, 2]
        if conv == "dh":
            _, d, a, alpha = g[i]
            oi = o + d * zp + a * xA
            Ri = RA @ _rx(alpha)
            elems += [(zp, o), (zp, None), (xA, None), (xA, oi)]
        else:
            _, a, alpha, beta = g[i]
            oi = o + a * xA
            RB = RA @ _rx(alpha)
            Ri = RB @ _ry(beta)
            elems += [(zp, o), (xA, None), (xA, oi), (RB[:, :, 1], oi)]
        R, o = Ri, oi
    p = o + R @ model.p_FQ
    R_TW = model.R_WT.T
    cols = [np.cross(u, p - oo) if oo is not None else u for u, oo in elems]  # 24 x (n,3)
    H = np.empty((n, 3, N_FULL), dtype=dtype)
    H[:, :, :24] = _rot(R_TW, np.stack(cols, axis=-1))
    H[:, :, 24:27] = -R_TW
    h = _rot(R_TW, (p - model.p_WT)[:, :, None])[:, :, 0]
    Gs = [
        np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float),
        np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], dtype=float),
        np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=float),
    ]
    assert np.allclose(model.p[27:30], 0.0)  # nominal model: rotation columns at r = 0
    for k, G in enumerate(Gs):
        H[:, :, 27 + k] = h @ G
    H[:, :, 30:33] = _rot(R_TW, R)
    return (H[:, :, problem.free] / problem.sigma).reshape(3 * n, -1)


def _rot(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """A (3,3) float times X (n,3,k) along axis 1, for float or object arrays."""
    return np.stack([sum(A[a, b] * X[:, b, :] for b in range(3)) for a in range(3)], axis=1)


def kpi_autodiff(problem: Problem, q: np.ndarray):
    """tr(Cs)/3 and its gradient (n, 6) through Drake AutoDiffXd."""
    import pydrake.math as pm
    from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

    n = q.shape[0]
    qa = InitializeAutoDiff(q.reshape(-1)).reshape(n, N_JOINTS)
    F1 = generic_F1(problem, qa)
    M = pm.matmul(F1.T.copy(), F1)
    Minv = pm.inv(M)
    Js = problem.Js()
    X = pm.matmul(Minv, Js.T.astype(object))
    val = sum(Js[a, c] * X[c, a] for a in range(3) for c in range(Js.shape[1])) / 3.0
    return float(val.value()), ExtractGradient(np.array([val])).reshape(n, N_JOINTS)


def finite_difference_grad(obj: design.DesignObjective, q: np.ndarray, h: float = 1e-7):
    """Forward differences of the closed-form value: 1 + 6n value evaluations."""
    f0 = obj.value(q)
    g = np.empty_like(q)
    for k in range(q.shape[0]):
        for j in range(N_JOINTS):
            qp = q.copy()
            qp[k, j] += h
            g[k, j] = (obj.value(qp) - f0) / h
    return f0, g


def _timeit(f, min_reps: int = 3, min_time: float = 1.0) -> tuple[float, float]:
    """Median wall and CPU time of f() [s] over at least min_reps calls and min_time seconds."""
    walls, cpus = [], []
    t_start = time.perf_counter()
    while len(walls) < min_reps or time.perf_counter() - t_start < min_time:
        w, c = time.perf_counter(), time.process_time()
        f()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
        if len(walls) >= 1000:
            break
    return statistics.median(walls), statistics.median(cpus)


# ----------------------------------------------------------------------------------------------
# Sections
# ----------------------------------------------------------------------------------------------
def bench_derivatives(problem: Problem, n: int = 60) -> tuple[list[str], dict]:
    q = design.heuristic_design(problem, n=n, seed=0)
    obj = design.DesignObjective(problem, "kpi")
    v_cf, g_cf = obj.value_and_grad(q)
    # faithfulness checks before timing
    F1_generic = generic_F1(problem, q.copy())
    assert np.allclose(F1_generic, problem.F1(q), rtol=1e-12, atol=1e-9), "generic F1 differs"
    v_ad, g_ad = kpi_autodiff(problem, q)
    v_fd, g_fd = finite_difference_grad(obj, q)
    scale = np.max(np.abs(g_cf))
    err_ad = float(np.max(np.abs(g_ad - g_cf)) / scale)
    err_fd = float(np.max(np.abs(g_fd - g_cf)) / scale)
    assert abs(v_ad - v_cf) <= 1e-10 * abs(v_cf) and err_ad < 1e-8, (v_ad, v_cf, err_ad)
    t_cf = _timeit(lambda: obj.value_and_grad(q), min_reps=20)
    t_val = _timeit(lambda: obj.value(q), min_reps=20)
    t_fd = _timeit(lambda: finite_difference_grad(obj, q), min_reps=3)
    t_ad = _timeit(lambda: kpi_autodiff(problem, q), min_reps=3)
    cons = design.DesignConstraints(problem, collision=True)
    t_con = _timeit(lambda: cons.evaluate(q), min_reps=20)
    rows = [
        "| method | wall [ms] | CPU [ms] | vs closed form | max. gradient error (rel. to max abs) |",
        "|---|---|---|---|---|",
        f"| closed form (value + gradient) | {1e3 * t_cf[0]:.2f} | {1e3 * t_cf[1]:.2f} | 1 | reference |",
        f"| closed form, value only | {1e3 * t_val[0]:.2f} | {1e3 * t_val[1]:.2f} | "
        f"{t_val[0] / t_cf[0]:.2f} | - |",
        f"| forward finite differences ({1 + 6 * n} values, h = 1e-7 rad) | {1e3 * t_fd[0]:.1f} | "
        f"{1e3 * t_fd[1]:.1f} | {t_fd[0] / t_cf[0]:.0f}x | {err_fd:.1e} |",
        f"| Drake AutoDiffXd (numpy object arrays, pydrake.math matmul/inv) | {1e3 * t_ad[0]:.1f} | "
        f"{1e3 * t_ad[1]:.1f} | {t_ad[0] / t_cf[0]:.0f}x | {err_ad:.1e} |",
        "",
        f"For scale: all {cons.rows_per_pose * n} constraint rows (incidence + {cons.rows_per_pose - 1} "
        f"clearances per pose) with their Jacobian, numpy closed form: {1e3 * t_con[0]:.2f} ms wall.",
    ]
    info = dict(closed_ms=1e3 * t_cf[0], fd_ms=1e3 * t_fd[0], ad_ms=1e3 * t_ad[0], ad_ratio=t_ad[0] / t_cf[0])
    return rows, info


def _solve(
    problem: Problem,
    n: int,
    seed: int,
    solver: str,
    active_rows=design.ACTIVE_ROWS_PER_POSE,
    max_block=design.MAX_BLOCK_POSES,
) -> dict:
    c0 = time.process_time()
    res = design.optimize_design(
        problem,
        criterion="kpi",
        n=n,
        seed=seed,
        solver=solver,
        allow_infeasible=True,
        active_rows=active_rows,
        max_block=max_block,
    )
    return dict(
        seed=seed,
        solver=solver,
        n=n,
        wall=res.solve_s,
        cpu=time.process_time() - c0,
        value=res.kpi_avg_var_mm2,
        start=res.initial_values[0],
        evals=res.n_evals,
        ok=bool(res.success and res.feasible),
        status=res.status,
        sweeps=res.sweeps,
    )


def bench_solvers(problem: Problem, seeds: list[int], n: int = 60) -> tuple[list[str], dict]:
    rows = [
        "| solver | seed | solve wall [s] | CPU [s] | cost evaluations | tr(Cs)/3 start -> end [mm^2] | "
        "success and feasible | status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    med = {}
    all_rows = f"snopt, all {design.DesignConstraints(problem).rows_per_pose - 1} clearance rows"
    configs = {
        "snopt": ("snopt", design.ACTIVE_ROWS_PER_POSE),
        "ipopt": ("ipopt", design.ACTIVE_ROWS_PER_POSE),
        all_rows: ("snopt", None),
    }
    for label, (solver, active_rows) in configs.items():
        runs = []
        for seed in seeds:
            r = _solve(problem, n, seed, solver, active_rows)
            runs.append(r)
            rows.append(
                f"| {label} | {seed} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['evals']} | "
                f"{r['start']:.4f} -> {r['value']:.4f} | {r['ok']} | {r['status']} |"
            )
            print(f"  {label} seed {seed}: {r['wall']:.2f} s, {r['value']:.4f}", file=sys.stderr, flush=True)
        med[label] = dict(
            wall=statistics.median(r["wall"] for r in runs),
            cpu=statistics.median(r["cpu"] for r in runs),
            value=statistics.median(r["value"] for r in runs),
            evals=statistics.median(r["evals"] for r in runs),
            n_ok=sum(r["ok"] for r in runs),
        )
    rows += [
        "",
        "| solver | median solve wall [s] | median CPU [s] | median tr(Cs)/3 [mm^2] | median evaluations | "
        "successful runs |",
        "|---|---|---|---|---|---|",
    ]
    for label, m in med.items():
        rows.append(
            f"| {label} | {m['wall']:.2f} | {m['cpu']:.2f} | {m['value']:.4f} | {m['evals']:.0f} | "
            f"{m['n_ok']}/{len(seeds)} |"
        )
    rows += [
        "",
        f"snopt and ipopt pass each pose's {design.ACTIVE_ROWS_PER_POSE} smallest clearances to the solver "
        f"(the default); the last configuration passes all of them (the same feasible set). Median wall "
        f"time, all rows / {design.ACTIVE_ROWS_PER_POSE} smallest: "
        f"{med[all_rows]['wall'] / med['snopt']['wall']:.1f}x.",
    ]
    return rows, med


def bench_sizes(problem: Problem, sizes: list[int]) -> tuple[list[str], dict]:
    """Solve time against N: SNOPT as configured by default (one solve up to
    ``design.MAX_BLOCK_POSES`` poses, block sweeps above), SNOPT in one solve over all poses, IPOPT."""
    one = "snopt, one solve"
    configs = {
        "snopt": ("snopt", design.MAX_BLOCK_POSES),
        one: ("snopt", None),
        "ipopt": ("ipopt", design.MAX_BLOCK_POSES),
    }
    rows = [
        "| N | variables | configuration | sweeps | wall [s] | CPU [s] | evaluations | tr(Cs)/3 [mm^2] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    runs = {label: [] for label in configs}
    for n in sizes:
        for label, (solver, max_block) in configs.items():
            if label == one and n <= design.MAX_BLOCK_POSES:
                r = runs["snopt"][-1]  # the default is one solve at this size: the same run
            else:
                r = _solve(problem, n, 0, solver, max_block=max_block)
            runs[label].append(r)
            flag = "" if r["ok"] else " (" + r["status"] + ")"
            rows.append(
                f"| {n} | {6 * n} | {label} | {r['sweeps']} | {r['wall']:.2f} | {r['cpu']:.2f} | "
                f"{r['evals']} | {r['value']:.5f}{flag} |"
            )
            print(f"  N={n} {label}: {r['wall']:.2f} s, {r['value']:.5f}", file=sys.stderr, flush=True)
    ln = np.log(np.asarray(sizes, dtype=float))

    def fit(values):
        return float(np.polyfit(ln, np.log(values), 1)[0])

    expo = {}
    for label, rs in runs.items():
        expo[label] = dict(
            wall=fit([r["wall"] for r in rs]),
            cpu=fit([r["cpu"] for r in rs]),
            per_eval=fit([r["cpu"] / max(r["evals"], 1) for r in rs]),
            evals=fit([r["evals"] for r in rs]),
        )
    rows += [
        "",
        f"Default: one solve up to {design.MAX_BLOCK_POSES} poses; above, sweeps over blocks of about "
        f"{design.SWEEP_BLOCK_POSES} poses, each solved with the other poses held fixed, until a sweep "
        f"lowers the criterion by less than {design.SWEEP_RTOL:g} (`design.MAX_BLOCK_POSES`). "
        f"'{one}' is SNOPT over all 6N variables at once (`max_block=None`; the same run as the default "
        f"up to {design.MAX_BLOCK_POSES} poses).",
        "",
    ]
    for label, e in expo.items():
        rows.append(
            f"- {label}: log-log fit t ~ N^p over N = {', '.join(map(str, sizes))}: p = {e['wall']:.2f} "
            f"(wall), {e['cpu']:.2f} (CPU); CPU time per evaluation grows as N^{e['per_eval']:.2f}, the "
            f"number of evaluations as N^{e['evals']:.2f}."
        )
    return rows, expo


def bench_breakdown(
    problem: Problem, solver_wall_s: float | None, evals: float | None, n: int = 60
) -> list[str]:
    """Where the time of one solver evaluation goes (60 poses): Drake's binding evaluations (our
    callbacks and the AutoDiffXd conversions) vs the rest (SNOPT)."""
    from pydrake.autodiffutils import InitializeAutoDiff

    q = design.heuristic_design(problem, n=n, seed=0)
    dp = design.DesignProgram(problem, criterion="kpi", n=n, collision=True)
    # two iterates in turn, so that every evaluation computes afresh (rows are kept per iterate)
    xads = [InitializeAutoDiff(q.reshape(-1)), InitializeAutoDiff(q.reshape(-1) + 1e-9)]
    blocks = []
    for b in dp.constraint_bindings:
        cols = [int(dp.prog.FindDecisionVariableIndex(v)) for v in b.variables()]
        blocks.append((b.evaluator(), cols))
    cost = dp.cost_binding.evaluator()
    state = {"i": 0}

    def one_iterate():
        x = xads[state["i"] % 2]
        state["i"] += 1
        cost.Eval(x)
        for ev, cols in blocks:
            ev.Eval(x[cols])

    one_iterate()
    cb0 = dp.counters.cost_s + dp.counters.constraint_s
    k = 40
    t0 = time.perf_counter()
    for _ in range(k):
        one_iterate()
    t_all = (time.perf_counter() - t0) / k
    t_cb = (dp.counters.cost_s + dp.counters.constraint_s - cb0) / k
    m = dp.active_rows
    obj, con = dp.objective, dp.constraints

    def numpy_only():
        fr = con.frames(q)
        obj.value_and_grad(q, frames=fr)
        con.evaluate_active(q, None, m, frames=fr)

    t_np = _timeit(numpy_only, min_reps=20)[0]
    rows = [
        "| part of one evaluation (60 poses) | wall [ms] |",
        "|---|---|",
        f"| Drake evaluates the cost and the {len(blocks)} constraint bindings (AutoDiffXd in and out) | "
        f"{1e3 * t_all:.1f} |",
        f"| - of which our callbacks (numpy + InitializeAutoDiff) | {1e3 * t_cb:.1f} |",
        f"| -- of which numpy: forward kinematics, tr(Cs)/3 and its gradient, incidence, all clearances "
        f"and the Jacobian of the {m} smallest per pose | {1e3 * t_np:.1f} |",
        f"| - of which Drake/pybind AutoDiffXd conversions (remainder) | {1e3 * (t_all - t_cb):.1f} |",
    ]
    if solver_wall_s and evals:
        per_it = solver_wall_s / evals
        rows.append(f"| SNOPT median solve wall time / median evaluations (section 2) | {1e3 * per_it:.1f} |")
        rows.append(f"| - remainder: SNOPT itself | {1e3 * (per_it - t_all):.1f} |")
    return rows


ONLY = {"humanoid": humanoid, "online": online_bench, "twin": twin_bench}
"""Sections ``--only`` runs alone, replacing them in the results file."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds for SNOPT vs IPOPT (default 5)")
    ap.add_argument("--sizes", default="15,30,60,120,240", help="numbers of poses for the growth study")
    ap.add_argument("--robot", default="kr16")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results.md"))
    skips = "derivatives,solvers,breakdown,sizes,fits,compensate,humanoid,online,twin"
    ap.add_argument("--skip", default="", help=f"sections to skip: {skips}")
    ap.add_argument(
        "--only",
        choices=["fits", "compensate", *ONLY],
        help="run only this section and replace it in --out",
    )
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    if args.only == "fits":
        print("\n".join(update_results(args.out)))
        return 0
    if args.only == "compensate":
        print("\n".join(compensate_bench.update_results(args.out)))
        return 0
    if args.only in ONLY:
        module = ONLY[args.only]
        rows, summary = module.bench_section()
        section = module.section_lines(rows, summary)
        path = Path(args.out)
        atomic_write_text(path, replace_section(path.read_text(), section, module.SECTION))
        print("\n".join(section))
        return 0
    from importlib.metadata import version

    problem = make_problem(args.robot)
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    head = [
        f"# Benchmark results ({args.robot}, KPI design)",
        "",
        f"Run {datetime.datetime.now().isoformat(timespec='seconds')} on {platform.machine()}, "
        f"{os.cpu_count()} CPUs, Python {platform.python_version()}, drake {version('drake')}, "
        f"numpy {np.__version__}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}. "
        f"Load average at start: {load0[0]:.2f}.",
        "",
    ]
    sections = []
    summary = {}
    if "derivatives" not in skip:
        print("derivatives ...", file=sys.stderr, flush=True)
        rows, summary["derivatives"] = bench_derivatives(problem)
        sections += [
            "## 1. Objective + gradient evaluation (60 poses, 360 variables, tr(Cs)/3)",
            "",
            *rows,
            "",
        ]
    if "solvers" not in skip:
        print("solvers ...", file=sys.stderr, flush=True)
        rows, summary["solvers"] = bench_solvers(problem, list(range(args.seeds)))
        sections += ["## 2. SNOPT vs IPOPT (KPI with collision avoidance, 60 poses)", "", *rows, ""]
    if "breakdown" not in skip:
        med = summary.get("solvers", {}).get("snopt", {})
        rows = bench_breakdown(problem, med.get("wall"), med.get("evals"))
        sections += ["## 2b. Where one SNOPT evaluation's time goes (60 poses, with CA)", "", *rows, ""]
    if "sizes" not in skip:
        print("sizes ...", file=sys.stderr, flush=True)
        sizes = [int(s) for s in args.sizes.split(",")]
        rows, summary["sizes"] = bench_sizes(problem, sizes)
        sections += ["## 3. Solve time vs number of poses (KPI with CA, seed 0)", "", *rows, ""]
    later = {
        "fits": (bench_fits, section_lines),
        "compensate": (compensate_bench.bench_compensate, compensate_bench.section_lines),
        "humanoid": (humanoid.bench_section, humanoid.section_lines),
        "online": (online_bench.bench_section, online_bench.section_lines),
        "twin": (twin_bench.bench_section, twin_bench.section_lines),
    }
    for name, (run, lines) in later.items():
        if name not in skip:
            print(f"{name} ...", file=sys.stderr, flush=True)
            rows, summary[name] = run()
            sections += lines(rows, summary[name])
    load1 = os.getloadavg()
    targets = ["## Targets", ""]
    if "solvers" in summary:
        m = summary["solvers"]["snopt"]["wall"]
        targets.append(
            f"- median KPI solve with CA <= 3 s: measured {m:.2f} s ({'met' if m <= 3 else 'NOT met'})"
        )
    if "derivatives" in summary:
        r = summary["derivatives"]["ad_ratio"]
        targets.append(
            f"- closed form >= 100x faster than AutoDiffXd: measured {r:.0f}x "
            f"({'met' if r >= 100 else 'NOT met'})"
        )
    if "sizes" in summary:
        for solver, e in summary["sizes"].items():
            p = e["wall"]
            targets.append(
                f"- growth no worse than N^1.5 ({solver}): measured N^{p:.2f} "
                f"({'met' if p <= 1.5 else 'NOT met'})"
            )
    if "fits" in summary:
        targets += targets_lines(summary["fits"])
    if "compensate" in summary:
        targets += compensate_bench.targets_lines(summary["compensate"])
    if "humanoid" in summary:
        targets += humanoid.targets_lines(summary["humanoid"])
    if "twin" in summary:
        targets += twin_bench.targets_lines(summary["twin"])
    foot = [
        "",
        f"Total benchmark time {time.perf_counter() - t0:.0f} s; load average at end: {load1[0]:.2f} "
        "(other processes on the machine inflate wall times; CPU times are this process's).",
    ]
    text = "\n".join(head + targets + [""] + sections + foot) + "\n"
    print(text)
    atomic_write_text(args.out, text)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
