"""One peer tool on one task: runs inside the peer's own environment, never the project's.

    .venv-peers/bin/python benchmarks/peers/fit_peer.py TOOL task.npz out.npz
    .venv-jaxsysid/bin/python benchmarks/peers/fit_peer.py TOOL task.npz out.npz

TOOL is one of ``narx`` and ``volterra`` (SysIdentPy FROLS), ``sindy`` (pysindy
DiscreteSINDy with control), ``jaxsysid_linear`` and ``jaxsysid_rnn`` (jax-sysid).
`benchmarks/peers/run.py` writes ``task.npz`` and reads ``out.npz``; it alone scores.

The task holds three records as 1-D arrays: ``fit_*`` (what the tool is fitted
on), ``sel_*`` (where each candidate setting of ``grid`` is simulated run free
from the first ``sel_init`` measured outputs and scored by RMSE over
``sel_lo:sel_hi``: the estimation data only) and ``test_*`` (simulated run free
from its first ``test_init`` measured outputs with the chosen setting; the test
outputs are never seen otherwise). The chosen setting is the one with the lowest
selection RMSE. ``out.npz`` holds the free-run prediction of the whole test
record (its first ``test_init`` samples are the measured ones), for ``narx``
also the one-step-ahead prediction, the seconds of the chosen setting's fit and
of the test simulation, and every candidate's selection RMSE.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def _rmse(a, b) -> float:
    d = np.asarray(a, float) - np.asarray(b, float)
    value = float(np.sqrt(np.mean(d * d)))
    return value if np.isfinite(value) else float("inf")


def _initial(y, init, n):
    """The first n output samples a simulation may start from: y[:init], then y[init-1] held."""
    y0 = np.asarray(y[: min(init, n)], float)
    return np.concatenate([y0, np.full(max(0, n - len(y0)), y0[-1])])


# --- SysIdentPy: polynomial NARX and Volterra (NFIR) by FROLS -------------------------------
def _frols(cfg, nfir):
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    options = dict(
        xlag=int(cfg["xlag"]),
        order_selection=True,
        info_criteria="aic",
        n_info_values=int(cfg.get("n_info_values", 15)),
        estimator=LeastSquares(),
        basis_function=Polynomial(degree=int(cfg["degree"])),
    )
    if nfir:
        options["model_type"] = "NFIR"
    else:
        options["ylag"] = int(cfg["ylag"])
    return FROLS(**options)


class SysIdentPy:
    def __init__(self, nfir):
        self.nfir = nfir

    def fit(self, cfg, u, y):
        model = _frols(cfg, self.nfir)
        model.fit(X=u[:, None], y=y[:, None])
        return model

    def simulate(self, model, u, y, init):
        y0 = _initial(y, init, model.max_lag)
        with np.errstate(all="ignore"):
            p = np.asarray(model.predict(X=u[:, None], y=y0[:, None]), float).ravel()
        return _fit_length(p, len(u))

    def one_step(self, model, u, y):
        with np.errstate(all="ignore"):
            p = np.asarray(model.predict(X=u[:, None], y=y[:, None], steps_ahead=1), float).ravel()
        return _fit_length(p, len(u))

    def describe(self, model):
        from sysidentpy.utils.display_results import results

        return [
            " ".join(map(str, r))
            for r in results(
                model.final_model, model.theta, model.err, model.n_terms, err_precision=4, dtype="sci"
            )
        ]


def _fit_length(p, n):
    if len(p) >= n:
        return p[:n]
    return np.concatenate([p, np.full(n - len(p), np.nan)])


# --- pysindy: discrete-time SINDy with control on delay coordinates -------------------------
class Sindy:
    """x_k = (y_k, ..., y_{k-d+1}), control (u_k, ..., u_{k-d+1}); signals standardised first."""

    def fit(self, cfg, u, y):
        import pysindy as ps

        d = int(cfg["delays"])
        self.scale = (float(np.mean(u)), float(np.std(u)) or 1.0, float(np.mean(y)), float(np.std(y)) or 1.0)
        x, c = self._embed(u, y, d)
        model = ps.DiscreteSINDy(
            optimizer=ps.STLSQ(threshold=float(cfg["threshold"]), alpha=1e-5),
            feature_library=ps.PolynomialLibrary(degree=int(cfg["degree"])),
        )
        model.fit(x, t=1, u=c)
        return (model, d, self.scale)

    def _embed(self, u, y, d, scale=None):
        um, us, ym, ys = scale or self.scale
        us_, ys_ = (u - um) / us, (y - ym) / ys
        n = len(u)
        x = np.stack([ys_[d - 1 - j : n - j] for j in range(d)], axis=1)
        c = np.stack([us_[d - 1 - j : n - j] for j in range(d)], axis=1)
        return x, c

    def simulate(self, fitted, u, y, init):
        model, d, scale = fitted
        if d > init:
            raise ValueError(f"delays {d} > the {init} samples a simulation may start from")
        um, us, ym, ys = scale
        yy = y.astype(float).copy()
        yy[d:] = 0.0  # nothing after the initial samples is seen
        x, c = self._embed(u, yy, d, scale)
        k0 = init - 1  # the state at sample init-1 holds y[init-d .. init-1]
        x0, cu = x[k0 - (d - 1)], c[k0 - (d - 1) :]
        steps = len(u) - k0
        sim = self._run(model, x0, cu, steps)
        out = np.full(len(u), np.nan)
        out[:init] = y[:init]
        out[k0 : k0 + len(sim)] = sim[:, 0] * ys + ym
        self.last = (model, x0, cu, steps, sim)
        return out

    @staticmethod
    def _run(model, x0, cu, steps):
        """pysindy's DiscreteSINDy.simulate, evaluated with the fitted library's own powers and coefficients.

        pysindy's simulate calls the scikit-learn pipeline once per step (about 5 ms a step here: 200 s for
        the Silverbox's arrow); this loop gives the same states (`check_simulate` compares them) in ~20 µs.
        """
        powers, coef = model.feature_library.powers_, model.coefficients()
        x = np.empty((steps, len(x0)))
        x[0] = x0
        with np.errstate(all="ignore"):
            for k in range(1, steps):
                z = np.concatenate([x[k - 1], cu[k - 1]])
                x[k] = coef @ np.prod(z[None, :] ** powers, axis=1)
                if not np.all(np.abs(x[k]) < 1e3):
                    return x[: k + 1]
        return x

    def check_simulate(self, steps=500):
        """(max |difference| to pysindy's own simulate over `steps` steps, its seconds per step)."""
        model, x0, cu, n, sim = self.last
        steps = min(steps, n)
        t0 = time.perf_counter()
        own = model.simulate(x0, t=steps, u=cu[:steps], stop_condition=lambda s: not np.all(np.abs(s) < 1e3))
        per_step = (time.perf_counter() - t0) / steps
        m = min(len(own), len(sim))
        return float(np.max(np.abs(own[:m] - sim[:m]))), per_step

    def describe(self, fitted):
        model = fitted[0]
        return [str(line) for line in model.equations(precision=4)]


# --- jax-sysid: linear state space, and the documented residual RNN -------------------------
class JaxSysid:
    def __init__(self, kind):
        self.kind = kind

    def fit(self, cfg, u, y):
        import jax
        import jax.numpy as jnp
        from jax_sysid.models import LinearModel, Model
        from jax_sysid.utils import standard_scale

        Ys, ym, yg = standard_scale(y[:, None])
        Us, um, ug = standard_scale(u[:, None])
        nx = int(cfg["nx"])
        if self.kind == "linear":
            model = LinearModel(nx, 1, 1, seed=0)
            model.loss(rho_x0=1e-3, rho_th=1e-2)
            model.optimization(lbfgs_epochs=int(cfg["lbfgs_epochs"]), iprint=-1)
        else:
            nn = int(cfg["neurons"])

            def sigmoid(x):
                return 1.0 / (1.0 + jnp.exp(-x))

            @jax.jit
            def state_fcn(x, u, params):
                A, B, C, W1, W2, W3, b1, b2, W4, W5, b3, b4 = params
                return A @ x + B @ u + W3 @ sigmoid(W1 @ x + W2 @ u + b1) + b2

            @jax.jit
            def output_fcn(x, u, params):
                A, B, C, W1, W2, W3, b1, b2, W4, W5, b3, b4 = params
                return C @ x + W5 @ sigmoid(W4 @ x + b3) + b4

            rng = np.random.default_rng(0)
            model = Model(nx, 1, 1, state_fcn=state_fcn, output_fcn=output_fcn)
            model.init(
                params=[
                    0.5 * np.eye(nx),
                    0.1 * rng.standard_normal((nx, 1)),
                    0.1 * rng.standard_normal((1, nx)),
                    0.1 * rng.standard_normal((nn, nx)),
                    0.5 * rng.standard_normal((nn, 1)),
                    0.5 * rng.standard_normal((nx, nn)),
                    np.zeros(nn),
                    np.zeros(nx),
                    0.5 * rng.standard_normal((nn, nx)),
                    0.5 * rng.standard_normal((1, nn)),
                    np.zeros(nn),
                    np.zeros(1),
                ]
            )
            model.loss(rho_x0=1e-4, rho_th=1e-4)
            model.optimization(
                adam_epochs=int(cfg["adam_epochs"]), lbfgs_epochs=int(cfg["lbfgs_epochs"]), iprint=-1
            )
        model.fit(Ys, Us)
        return (
            model,
            (float(np.ravel(um)[0]), float(np.ravel(ug)[0]), float(np.ravel(ym)[0]), float(np.ravel(yg)[0])),
        )

    def simulate(self, fitted, u, y, init):
        model, (um, ug, ym, yg) = fitted
        Us, Ys = ((u - um) / ug)[:, None], ((y - ym) / yg)[:, None]
        x0 = model.learn_x0(Us[:init], Ys[:init], verbosity=False)
        with np.errstate(all="ignore"):
            Yhat, _ = model.predict(x0, Us)
        out = np.asarray(Yhat, float).ravel() * yg + ym
        out[:init] = y[:init]
        return out

    def describe(self, fitted):
        return [f"states {fitted[0].nx}"]


TOOLS = {
    "narx": lambda: SysIdentPy(False),
    "volterra": lambda: SysIdentPy(True),
    "sindy": Sindy,
    "jaxsysid_linear": lambda: JaxSysid("linear"),
    "jaxsysid_rnn": lambda: JaxSysid("rnn"),
}


def main(argv) -> int:
    if len(argv) != 3 or argv[0] not in TOOLS:
        print(f"usage: fit_peer.py {{{','.join(TOOLS)}}} task.npz out.npz", file=sys.stderr)
        return 2
    name, task_path, out_path = argv
    task = np.load(task_path)
    grid = json.loads(str(task["grid"]))
    tool = TOOLS[name]()
    f_u, f_y = task["fit_u"].astype(float), task["fit_y"].astype(float)
    s_u, s_y, s_init = task["sel_u"].astype(float), task["sel_y"].astype(float), int(task["sel_init"])
    lo, hi = int(task["sel_lo"]), int(task["sel_hi"])
    t_u, t_y, t_init = task["test_u"].astype(float), task["test_y"].astype(float), int(task["test_init"])
    t_search = time.perf_counter()
    candidates, best = [], None
    for cfg in grid:
        t0 = time.perf_counter()
        try:
            fitted = tool.fit(cfg, f_u, f_y)
            fit_s = time.perf_counter() - t0
            score = _rmse(tool.simulate(fitted, s_u, s_y, s_init)[lo:hi], s_y[lo:hi])
            error = ""
        except Exception as e:  # a setting a tool cannot fit is recorded, not fatal
            fitted, fit_s, score, error = (
                None,
                time.perf_counter() - t0,
                float("inf"),
                f"{type(e).__name__}: {e}",
            )
        candidates.append({"settings": cfg, "selection_rmse": score, "fit_s": fit_s, "error": error[:300]})
        print(f"{name} {cfg}: selection RMSE {score:.4g} ({fit_s:.1f} s) {error[:120]}", flush=True)
        if fitted is not None and (best is None or score < best[0]):
            best = (score, cfg, fitted, fit_s)
    search_s = time.perf_counter() - t_search
    if best is None:
        print(f"{name}: no setting could be fitted", file=sys.stderr)
        return 1
    _, cfg, fitted, fit_s = best
    t0 = time.perf_counter()
    free = tool.simulate(fitted, t_u, t_y, t_init)
    sim_s = time.perf_counter() - t0
    out = {
        "free": free,
        "fit_s": fit_s,
        "sim_s": sim_s,
        "search_s": search_s,
        "chosen": json.dumps(cfg),
        "candidates": json.dumps(candidates),
    }
    if hasattr(tool, "check_simulate"):
        difference, per_step = tool.check_simulate()
        out["tool_sim_s"] = per_step * (len(t_u) - t_init + 1)
        out["sim_note"] = (
            f"pysindy's own simulate: {per_step * 1e3:.2f} ms a step, timed on 500 steps and "
            f"extrapolated to the record; the prediction is computed with its coefficients and "
            f"library powers in a numpy loop ({sim_s:.2f} s; max difference "
            f"to pysindy's simulate {difference:.1e} over those steps)"
        )
    if hasattr(tool, "one_step"):
        out["one_step"] = tool.one_step(fitted, t_u, t_y)
    try:
        out["model"] = json.dumps(tool.describe(fitted)[:40])
    except Exception as e:  # the description is a courtesy
        out["model"] = json.dumps([f"(no description: {e})"])
    np.savez(out_path, **out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
