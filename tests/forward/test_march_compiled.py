"""The compiled marching backend against the NumPy reference, effect subset by subset.

Parameter sets are drawn from the central 60 % of every parameter's range.  In the far
corners (a soft frame and a ram slowing by ~90 % under load, closing for hundreds of
seconds) the step sequence is sensitive to round-off, and the two paths may then differ by
up to the time-discretisation error (~1 % of the force limit around the switch).  With a
compliant frame and a ram slowing under load the step control amplifies round-off
mildly (up to ~1e-5 relative over a run); a transcription error shows at 1e-3 or more.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings
from pathlib import Path

import numpy as np
import pytest

from smcbayes.config import ProjectConfig, load_project
from smcbayes.errors import SlowPathWarning
from smcbayes.forward import march_compiled
from smcbayes.forward.effects.thermal import Heating
from smcbayes.forward.kernel_layout import KERNEL_EFFECTS
from smcbayes.forward.march import march
from smcbayes.forward.model import ForwardModel
from smcbayes.forward.parameters import to_si
from smcbayes.forward.squeeze1d import material_table

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "thesis.toml"
SUPPORTED = sorted(cls.name for cls in KERNEL_EFFECTS)
SUBSETS = [s for r in range(1, 6) for s in itertools.combinations(SUPPORTED, r)]
# a bar and a centre charge with the square-charge correction
CONFIGS = ("60-bar-03", "80-center-07")
# the Moldflow-card box of the thesis (section 4.4) for the base parameters: the comparison
# stays on the parameters it was set up with when the project's search box changes
CARD = {"n": (0.2, 0.6), "tau_star_Pa": (1e3, 1e5), "B_Pa_s": (1e3, 1e5), "tau_c_MPa": (0.005, 1.0),
        "m": (1.0, 1.9)}


@pytest.fixture(scope="module")
def project() -> ProjectConfig:
    """The thesis project without its fixed effect parameters: every kernel slot is varied."""
    full = load_project(CONFIG)
    return full.model_copy(update={"parameters": {k: v for k, v in full.parameters.items() if k in CARD}})


@pytest.mark.parametrize("subset", SUBSETS, ids="+".join)
def test_compiled_nodes_equal_the_numpy_march(project: ProjectConfig, subset: tuple[str, ...]) -> None:
    model = ForwardModel(project, effects=list(subset))
    space = model.space.with_bounds(CARD)
    u = 0.2 + 0.6 * np.random.default_rng(0).random((8, space.dim))
    names = [q.name for q in space.parameters]
    if "bulk_viscosity_MPa_s" in names:  # rate-independent compaction (the default) too
        u[::2, names.index("bulk_viscosity_MPa_s")] = 0.0
    theta = space.from_unit(u)
    p = to_si(space.batch(theta), space.parameters)
    options = model.solver.options
    table = material_table(p, project.material, model.solver.tau)
    for cid in CONFIGS:
        case = model.cases[cid]
        ref = march(case, p, model.effects, table, options)
        out = march_compiled.march_compiled(case, p, model.effects, table, options)
        assert out.status == ref.status
        np.testing.assert_array_equal(out.count, ref.count)
        np.testing.assert_allclose(out.switch, ref.switch, rtol=1e-4)
        for name in ("time", "gap", "area", "force", "deflection", "solid"):
            np.testing.assert_allclose(getattr(out, name), getattr(ref, name), rtol=1e-4,
                                       atol=1e-12 * case.force_limit if name == "force" else 0.0,
                                       err_msg=f"{cid}: {name}")


def test_solver_takes_the_compiled_path_only_where_supported(project: ProjectConfig) -> None:
    compiled = ForwardModel(project, effects=["compressibility", "press_compliance"])
    assert march_compiled.supports(compiled.effects, compiled.cases["60-bar-03"])
    reference = ForwardModel(project, effects=["compressibility", "press_compliance"])
    reference.solver.options = dataclasses.replace(reference.solver.options, compiled=False)
    runs = march_compiled.RUNS["compiled"]
    a = compiled.simulate(None, ["60-bar-03"])["60-bar-03"]
    # the comparison below is only meaningful if the kernel ran, and ran only once
    assert compiled.solver.last_path == "compiled"
    assert march_compiled.RUNS["compiled"] == runs + 1
    b = reference.simulate(None, ["60-bar-03"])["60-bar-03"]
    assert reference.solver.last_path == "numpy"
    assert march_compiled.RUNS["compiled"] == runs + 1
    np.testing.assert_allclose(a.force_kN, b.force_kN, rtol=1e-9)
    np.testing.assert_allclose(a.displacement_mm, b.displacement_mm, rtol=1e-9)
    profiled = dataclasses.replace(compiled.cases["60-bar-03"], profile=object())
    assert not march_compiled.supports(compiled.effects, profiled)


class _WarmCharge(Heating):
    """A user's variant of a built-in effect: the kernel does not know its hooks."""

    name = "warm_charge"


def test_an_effect_unknown_to_the_kernel_runs_numpy_and_warns_once(project: ProjectConfig) -> None:
    model = ForwardModel(project, effects=["heating"])
    model.effects = type(model.effects)([_WarmCharge()])
    assert not march_compiled.supports(model.effects, model.cases["60-bar-03"])
    assert model.solver.slow_path(model.cases["60-bar-03"], model.effects) == ["effect 'warm_charge'"]
    with pytest.warns(SlowPathWarning, match="warm_charge") as record:
        model.warn_slow_path()
    assert len(record) == 1 and "slower" in str(record[0].message)
    model.simulate(None, ["60-bar-03"])
    assert model.solver.last_path == "numpy"
    model.solver.options = dataclasses.replace(model.solver.options, compiled=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SlowPathWarning)
        model.warn_slow_path()  # asked for: no warning
