"""Where a `diagnose` call spends its time, stage by stage (compiled programs reused).

    python benchmarks/diagnose_stages.py [--duration 300] [--rate 30]

Diagnoses one synthetic strip with a hidden back-relaxation (seed 0 of
`hybrid.ipmc._synthetic.random_strip`, the discrepancy drive) to compile the
search, then another of the same length with ``progress=True``, and prints
each stage's seconds from the stage messages: what a lab sees from its second
recording on. Prints only; nothing is written.
"""

from __future__ import annotations

import builtins
import time

import _common as c


def main() -> None:
    args = c.recording_arguments(__doc__)
    c.setup_jax()
    from hybrid import diagnose

    first, second = (c.relaxing_strip(seed, args.duration, args.rate) for seed in (0, 1))
    diagnose(first)
    start = time.perf_counter()
    last = [start]
    plain = builtins.print

    def timed_print(*parts, **options):
        now = time.perf_counter()
        plain(f"[{now - start:6.1f} s, +{now - last[0]:5.1f}]", *parts, **options)
        last[0] = now

    builtins.print = timed_print
    try:
        found = diagnose(second, progress=True)
    finally:
        builtins.print = plain
    print(f"second call: {time.perf_counter() - start:.1f} s, named {found.cause}")


if __name__ == "__main__":
    main()
