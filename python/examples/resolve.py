"""The intra-operative re-solve loop from Python, on cases/brain-shift.toml.

The model is prepared once; it is solved from the unloaded state, then the measured cortical
displacements grow by 10 % (as a new registration would give them) and it is solved again
from the first equilibrium. With the static solve (the default here) the model keeps its
factorized tangent stiffness at the equilibrium, and the re-solve takes a few modified-Newton
steps with it (brain-shift, 2 threads: 0.10 s, no assembly, no factorization); relaxation
(`relaxation` as the third argument) starts from the equilibrium and relaxes only the change.
Run from the repository root:

    python python/examples/resolve.py [SCENE] [MEASURED-NAME] [static|relaxation]
"""

import sys
import time

import hytled


def main(scene="cases/brain-shift.toml", measured="exposed", mode="static"):
    t0 = time.perf_counter()
    model = hytled.Model(scene, overrides={"solver.mode": mode})
    print(f"prepared {len(model.nodes)} nodes in {time.perf_counter() - t0:.2f} s")

    def line(r):
        s = r.summary
        extra = ""
        if s.get("static"):
            st = s["static"]
            extra = (f", {st['kept_solves']} kept-factor steps, {st['assemblies']} assemblies, "
                     f"{st['factorizations']} factorizations")
        return (f"{s['force_evaluations']} force evaluations{extra}, "
                f"{r.wall_seconds['solve']:.3f} s")

    first = model.solve()
    print(f"first solve ({mode}, from the unloaded state): {line(first)}")

    u = model.measured_displacements(measured) * 1.1
    model.set_measured(measured, u)
    again = model.solve()
    print(f"re-solve after +10 % (warm: {again.warm}): {line(again)}")
    for name, d in again.probes.items():
        print(f"  probe {name}: {d} m")
    return first, again


if __name__ == "__main__":
    main(*sys.argv[1:])
