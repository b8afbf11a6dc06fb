"""Tests of the join options (igljoin.options.JoinOptions)."""

from __future__ import annotations

import dataclasses
import json
import math
import warnings

import numpy as np
import pytest

from igljoin.errors import IgljoinError, OptionsError
from igljoin.options import DEPRECATED, JoinOptions

NAMES = sorted(f.name for f in dataclasses.fields(JoinOptions))


def test_options_error_is_a_value_error():
    assert issubclass(OptionsError, IgljoinError)
    assert issubclass(OptionsError, ValueError)


def test_defaults_are_valid():
    opt = JoinOptions()
    for f in dataclasses.fields(JoinOptions):
        assert getattr(opt, f.name) == f.default
    # every default passes validation when given explicitly too
    again = JoinOptions(**{f.name: f.default for f in dataclasses.fields(JoinOptions)})
    assert again == opt


def test_options_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        JoinOptions().energy_tolerance = 1.0


def test_numbers_are_stored_as_float():
    opt = JoinOptions(shape_weight=2, smooth_weight=np.float32(0.5), energy_tolerance=np.int64(1))
    assert type(opt.shape_weight) is float and opt.shape_weight == 2.0
    assert type(opt.smooth_weight) is float and opt.smooth_weight == 0.5
    assert type(opt.energy_tolerance) is float and opt.energy_tolerance == 1.0


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("shape_weight", -1.0),
        ("stretch_weight", -0.1),
        ("smooth_weight", -1e-9),
        ("smooth_radius", -1.0),
        ("shape_weight", math.nan),
        ("smooth_weight", math.inf),
        ("stretch_weight", "1"),
        ("shape_weight", True),
        ("shape_weight", None),
        ("energy_tolerance", 0.0),
        ("energy_tolerance", -1e-5),
        ("energy_tolerance", math.nan),
        ("energy_tolerance", math.inf),
        ("max_iterations", 0),
        ("max_iterations", -3),
        ("max_iterations", 1.5),
        ("max_iterations", 10.0),
        ("max_iterations", True),
        ("snap_fraction", 0.5),
        ("snap_fraction", 0.7),
        ("snap_fraction", -0.1),
        ("snap_fraction", math.nan),
        ("acceleration", -1),
        ("acceleration", 51),
        ("acceleration", 2.0),
        ("acceleration", True),
        ("smooth_keep_deg", 90.0),
        ("smooth_keep_deg", 120),
        ("smooth_keep_deg", -1.0),
        ("smooth_keep_deg", math.nan),
        ("time_limit", 0.0),
        ("time_limit", -1.0),
        ("time_limit", math.nan),
    ],
)
def test_number_out_of_range(name, value):
    with pytest.raises(OptionsError, match=rf"^{name}="):
        JoinOptions(**{name: value})


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("shape_weight", 0.0),
        ("smooth_weight", 0.0),
        ("snap_fraction", 0.0),
        ("snap_fraction", 0.49),
        ("acceleration", 0),
        ("acceleration", 50),
        ("max_iterations", 1),
        ("max_iterations", np.int64(3)),
        ("smooth_keep_deg", 0.0),
        ("smooth_keep_deg", 89.9),
        ("time_limit", 0.5),
        ("smooth", np.bool_(False)),
    ],
)
def test_values_at_the_edge_of_the_range_are_accepted(name, value):
    assert getattr(JoinOptions(**{name: value}), name) == value


def test_shape_and_stretch_both_zero():
    with pytest.raises(OptionsError, match="shape_weight and stretch_weight are both 0"):
        JoinOptions(shape_weight=0, stretch_weight=0.0)
    JoinOptions(shape_weight=0.0)  # one of them is enough
    JoinOptions(stretch_weight=0.0)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("smooth_mode", "Paper"),
        ("smooth_mode", None),
        ("laplacian", "cot"),
        ("stiffness_on", "edge"),
        ("initial_guess", "zero"),
        ("initial_guess", ""),
    ],
)
def test_enum_strings(name, value):
    with pytest.raises(OptionsError, match=rf"^{name}=.* is not one of '"):
        JoinOptions(**{name: value})


@pytest.mark.parametrize("name", ["smooth", "rotation_aware"])
@pytest.mark.parametrize("value", ["yes", 1, 0, None])
def test_bool_options(name, value):
    with pytest.raises(OptionsError, match=rf"^{name}=.* must be True or False"):
        JoinOptions(**{name: value})


@pytest.mark.parametrize(
    "value",
    [[-1.0, 1.0], [0.0, 1.0], [math.nan, 1.0], [1.0, math.inf], [[1.0, 1.0]], 2.0],
    ids=["negative", "zero", "nan", "inf", "2-d", "scalar"],
)
def test_bad_stiffness(value):
    with pytest.raises(OptionsError, match="^stiffness must be a 1-D array of positive finite"):
        JoinOptions(stiffness=value)


def test_non_numeric_stiffness():
    with pytest.raises(OptionsError, match="stiffness"):
        JoinOptions(stiffness=["soft", "hard"])


def test_empty_stiffness():
    with pytest.raises(OptionsError, match="stiffness"):
        JoinOptions(stiffness=[])


def test_stiffness_is_stored_as_float_array():
    opt = JoinOptions(stiffness=[1, 2, 4])
    assert isinstance(opt.stiffness, np.ndarray) and opt.stiffness.dtype == np.float64
    np.testing.assert_array_equal(opt.stiffness, [1.0, 2.0, 4.0])


# ----------------------------------------------------------------------------
# make, replace, to_json
# ----------------------------------------------------------------------------


def test_make_from_none_dict_and_instance():
    assert JoinOptions.make() == JoinOptions()
    assert JoinOptions.make({"energy_tolerance": 1e-3}).energy_tolerance == 1e-3
    base = JoinOptions(energy_tolerance=1e-3, smooth=False)
    opt = JoinOptions.make(base, max_iterations=7)
    assert (opt.energy_tolerance, opt.smooth, opt.max_iterations) == (1e-3, False, 7)
    # keyword overrides win over the mapping
    assert JoinOptions.make({"max_iterations": 3}, max_iterations=4).max_iterations == 4


def test_make_unknown_keys_lists_valid_ones():
    with pytest.raises(OptionsError) as info:
        JoinOptions.make({"tolerence": 1e-3}, smoth=True)
    msg = str(info.value)
    assert "unknown join options ['smoth', 'tolerence']" in msg
    assert "valid options are " + ", ".join(NAMES) in msg


def test_make_validates():
    with pytest.raises(OptionsError, match="^acceleration="):
        JoinOptions.make({"acceleration": 99})


def test_the_acceleration_message_names_the_real_default():
    default = next(f.default for f in dataclasses.fields(JoinOptions) if f.name == "acceleration")
    with pytest.raises(OptionsError, match=f"the default is {default}\\)$"):
        JoinOptions(acceleration=-1)


def test_replace_validates_and_keeps_the_rest():
    opt = JoinOptions(smooth=False, stiffness=[1.0, 3.0])
    new = opt.replace(energy_tolerance=1e-3)
    assert new.energy_tolerance == 1e-3 and new.smooth is False
    np.testing.assert_array_equal(new.stiffness, [1.0, 3.0])
    assert opt.energy_tolerance == JoinOptions().energy_tolerance  # the original is unchanged
    with pytest.raises(OptionsError, match="^energy_tolerance="):
        opt.replace(energy_tolerance=-1.0)
    with pytest.raises(OptionsError, match="unknown join options"):
        opt.replace(tol=1.0)


def test_to_json_defaults():
    out = JoinOptions().to_json()
    assert sorted(out) == NAMES
    assert json.loads(json.dumps(out)) == out


def test_to_json_summarises_stiffness():
    out = JoinOptions(stiffness=np.array([0.5, 2.0, 1.0]), time_limit=3).to_json()
    text = json.dumps(out)
    back = json.loads(text)
    assert back["stiffness"] == {"count": 3, "min": 0.5, "max": 2.0}
    assert back["time_limit"] == 3.0


def test_to_json_with_numpy_scalars():
    opt = JoinOptions(max_iterations=np.int64(10), acceleration=np.int32(2), smooth=np.bool_(True))
    back = json.loads(json.dumps(opt.to_json()))
    assert back["max_iterations"] == 10 and back["acceleration"] == 2 and back["smooth"] is True


# --------------------------------------------------------------------------- structural options

#: A valid value other than the default, per option (every option is listed:
#: a new option fails the test below until it gets one here).
_CHANGED = {
    "smooth": False,
    "shape_weight": 2.0,
    "stretch_weight": 2.0,
    "smooth_weight": 3.0,
    "smooth_mode": "paper",
    "smooth_band": 3.0,
    "join_angle": 20.0,
    "join_side": "normal",
    "smooth_radius": 2.0,
    "smooth_keep_deg": 5.0,
    "laplacian": "cotangent",
    "rotation_aware": False,
    "stiffness": "twice",  # filled in with the guest's size below
    "stiffness_on": "vertex",
    "max_iterations": 9,
    "energy_tolerance": 1e-3,
    "time_limit": 1e6,
    "snap_fraction": 0.3,
    "initial_guess": "rigid",
    "acceleration": 0,
    "preconditioner": "two-level",
    "linear_solver": "igl",
}


def test_every_option_says_whether_it_is_structural():
    for f in dataclasses.fields(JoinOptions):
        assert isinstance(f.metadata.get("structural"), bool), f.name

    @dataclasses.dataclass(frozen=True)
    class Extended(JoinOptions):
        new_weight: float = 1.0  # says nothing: structural_fields refuses it

    with pytest.raises(TypeError, match="new_weight"):
        Extended.structural_fields()


def test_update_refactors_exactly_for_structural_options_and_skipping_it_is_safe():
    """``JoinSolver.update`` rebuilds the system for the marked options only, and a
    per-solve option changed without a rebuild solves as a fresh solver does."""
    from igljoin import JoinSolver, phantoms

    assert sorted(_CHANGED) == NAMES
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    base = {"max_iterations": 25}
    structural = set(JoinOptions.structural_fields())
    assert structural and structural < set(NAMES)
    for name, value in _CHANGED.items():
        if name == "stiffness":
            value = np.full(s.guest.n_vertices, 2.0)
        solver = JoinSolver(*args, **base)
        system = solver.solver
        solver.update(**{name: value})
        assert (solver.solver is not system) == (name in structural), name
        if name not in structural:
            fresh = JoinSolver(*args, **{**base, name: value}).solve()
            # the same arithmetic in the same order: bit for bit
            np.testing.assert_array_equal(solver.solve().guest.V, fresh.guest.V, err_msg=name)


def test_make_does_not_validate_an_instance_again():
    opt = JoinOptions(energy_tolerance=1e-3)
    assert JoinOptions.make(opt) is opt  # frozen and validated when built
    assert JoinOptions.make(opt, energy_tolerance=1e-4) is not opt


@pytest.mark.parametrize("bad", [-1.0, 90.0, float("nan"), "45", True, [30.0, "a"], []])
def test_join_angle_out_of_range_is_refused_with_its_range(bad):
    with pytest.raises(OptionsError, match="join_angle"):
        JoinOptions(join_angle=bad)


def test_join_angle_per_seam_must_match_the_seams():
    from igljoin import JoinSolver, phantoms

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    assert JoinOptions(join_angle=[10, None]).join_angle == (10.0, None)
    with pytest.raises(OptionsError, match="one per seam"):
        JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve, join_angle=[10.0, 20.0])
    with pytest.raises(OptionsError, match="join_side"):
        JoinOptions(join_side="up")


# ------------------------------------------------------------------- renamed options


_RENAMED = [
    ("tolerance", "energy_tolerance", 1e-3),
    ("snap_tolerance", "snap_fraction", 0.3),
    ("smooth_tolerance", "smooth_keep_deg", 5.0),
]


@pytest.mark.parametrize(("old", "new", "value"), _RENAMED)
def test_old_option_names_still_work_and_warn(old, new, value):
    assert DEPRECATED[old] == new
    with pytest.warns(DeprecationWarning, match=f"{old} is now called {new}") as caught:
        opt = JoinOptions(**{old: value})
    assert getattr(opt, new) == value
    # the warning points at the caller's line, not into igljoin
    assert [w.filename for w in caught] == [__file__]
    with pytest.warns(DeprecationWarning, match=new):
        assert getattr(JoinOptions.make({old: value}), new) == value
    with pytest.warns(DeprecationWarning, match=new):
        assert getattr(JoinOptions().replace(**{old: value}), new) == value


@pytest.mark.parametrize(("old", "new", "value"), _RENAMED)
def test_new_option_names_do_not_warn(old, new, value):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert getattr(JoinOptions(**{new: value}), new) == value
        assert getattr(JoinOptions.make({new: value}), new) == value
    assert new in JoinOptions().to_json() and old not in JoinOptions().to_json()


@pytest.mark.parametrize(("old", "new", "value"), _RENAMED)
def test_old_and_new_name_together_are_refused(old, new, value):
    with pytest.raises(OptionsError, match=f"{old} and {new} are the same option.*give only {new}"):
        JoinOptions(**{old: value, new: value})
    with pytest.raises(OptionsError, match=f"give only {new}"):
        JoinOptions.make({old: value, new: value})


def test_join_and_solver_take_the_old_names_with_a_warning():
    from igljoin import JoinSolver, join, phantoms

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    args = (s.host, s.guest, s.host_curve, s.guest_curve)
    with pytest.warns(DeprecationWarning, match="tolerance is now called energy_tolerance"):
        res = join(*args, tolerance=1e-3, max_iterations=5)
    assert res.options.energy_tolerance == 1e-3
    solver = JoinSolver(*args, max_iterations=5)
    with pytest.warns(DeprecationWarning, match="snap_fraction"):
        res = solver.solve(snap_tolerance=0.2)
    assert solver.options.snap_fraction == 0.2 and res.options.snap_fraction == 0.2
    with pytest.raises(OptionsError, match="give only energy_tolerance"):
        join(*args, tolerance=1e-3, energy_tolerance=1e-3)
