"""Jacobian of V_o with respect to the six physical parameters: forward mode vs finite differences.

    python benchmarks/jacobian.py

`hybrid.sensitivity.local_sensitivities` (one `jax.jacfwd` through the
block-lifted cascade, mapped to physical units) against central finite
differences of `scipy.signal.sosfilt` with the same sections, rebuilt from the
perturbed parameters (12 filter runs, relative step 1e-6). 10⁴ samples, N = 45.
Reports both times (compile apart) and the largest difference per parameter,
relative to max |∂V_o/∂θ|. Writes `benchmarks/results/jacobian.json`.
"""

from __future__ import annotations

import time

import _common as c
import numpy as np
from simulate import DT, drive


def run(repeats=5):
    c.setup_jax()
    import scipy.signal

    import hybrid as hy
    from hybrid import sensitivity as S

    x = drive()
    net = hy.RCNetwork(xi_rho=12.0, alpha_E=0.4, alpha_I=0.6, alpha_C=0.45, C_clamp=0.03)
    t0 = time.perf_counter()
    sens = S.local_sensitivities(net, x, DT)
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sens = S.local_sensitivities(net, x, DT)
        times.append(time.perf_counter() - t0)
    ours = min(times)

    perturbed = []
    for name in sens.names:
        value = sens.values[name]
        step = 1e-6 * value
        perturbed.append(
            (
                c.sos_sections(net.replace(**{name: value + step}), DT),
                c.sos_sections(net.replace(**{name: value - step}), DT),
                step,
            )
        )

    def finite_differences():  # the filter runs only: the sections are precomputed
        return np.stack(
            [
                (scipy.signal.sosfilt(hi, x) - scipy.signal.sosfilt(lo, x)) / (2 * step)
                for hi, lo, step in perturbed
            ],
            axis=1,
        )

    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        fd = finite_differences()
        times.append(time.perf_counter() - t0)
    errors = {n: c.relative_error(sens.jacobian[:, j], fd[:, j]) for j, n in enumerate(sens.names)}
    return {
        "samples": int(x.size),
        "parameters": list(sens.names),
        "jacfwd_s": ours,
        "jacfwd_first_call_s": first,
        "finite_differences_sosfilt_s": min(times),
        "note": "finite differences: 12 sosfilt runs with precomputed sections; jacfwd: sections, "
        "tangents and the mapping to physical units included",
        "max_relative_difference": max(errors.values()),
        "relative_difference_per_parameter": errors,
    }


def main():
    c.setup_jax()
    out = {"command": "python benchmarks/jacobian.py", "machine": c.machine(), **run()}
    print(out)
    c.write("jacobian.json", out)


if __name__ == "__main__":
    main()
