"""Every built FMU's model description says where it comes from (version, author, copyright, licence, generation tool
and date, the same in FMI 2 and 3) and gives every Float64 variable a unit defined in its UnitDefinitions, the
dimensionless ones unit "1"; the generator writes the same files on every run (the date is the sources', not the
clock's)."""
from __future__ import annotations

import re
from pathlib import Path

import fmpy
import pytest

from fmu_helpers import all_fmus, fmu_id, model_of, require_fmu, split_fmu_name

FMUS = all_fmus()


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


def test_description_names_version_author_copyright_licence_and_generation(fmu: Path) -> None:
    from milling_twin import __version__
    from milling_twin.models.codegen import AUTHOR, GENERATION_TOOL, licence

    md = fmpy.read_model_description(str(fmu))
    assert md.version == __version__
    assert md.author == AUTHOR
    assert md.license == licence() and md.license.strip()
    assert md.generationTool == GENERATION_TOOL and __version__ in md.generationTool
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", md.generationDateAndTime), md.generationDateAndTime
    assert md.copyright == f"Copyright {md.generationDateAndTime[:4]} {AUTHOR}"


def test_every_float64_variable_has_a_defined_unit(fmu: Path) -> None:
    md = fmpy.read_model_description(str(fmu))
    units = {u.name: u for u in md.unitDefinitions}
    model = model_of(fmu)
    for v in md.modelVariables:
        if v.type not in ("Real", "Float64"):
            assert v.unit is None, f"{v.name}: a {v.type} variable with a unit"
            continue
        assert v.unit in units, f"{fmu.name}: {v.name} has unit {v.unit!r}, not defined in UnitDefinitions"
        if v.name != "time":
            own = model.variable(v.name.split("[")[0]).unit
            assert v.unit == (own or "1"), f"{v.name}: unit {v.unit!r}, the model says {own!r}"
        if v.displayUnit is not None:
            assert v.displayUnit in [d.name for d in units[v.unit].displayUnits], v.name
    if "1" in units:  # the dimensionless unit: every exponent 0
        base = units["1"].baseUnit
        assert all(getattr(base, k) == 0 for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad"))


def test_jerk_limits_are_in_metres_per_second_cubed() -> None:
    path = next((p for p in FMUS if split_fmu_name(p)[0] == "Interpolator"), None)
    if path is None:
        pytest.skip("no Interpolator FMU built")
    md = fmpy.read_model_description(str(require_fmu(path)))
    variables = {v.name: v for v in md.modelVariables}
    for name in ("jerk", "axis_jerk_x", "axis_jerk_y", "axis_jerk_z"):
        assert variables[name].unit == "m/s3" and variables[name].displayUnit == "mm/s3", name
    unit = next(u for u in md.unitDefinitions if u.name == "m/s3")
    assert (unit.baseUnit.m, unit.baseUnit.s) == (1, -3)
    assert [(d.name, d.factor) for d in unit.displayUnits] == [("mm/s3", 1000.0)]


def test_generation_is_deterministic_and_follows_source_date_epoch(tmp_path: Path, monkeypatch) -> None:
    from milling_twin.models import MODELS
    from milling_twin.models.codegen import generate, generation_time

    model = MODELS["SpindlePower"]
    generate(model, tmp_path / "a", ["model.c"])
    generate(model, tmp_path / "b", ["model.c"])
    for name in ("fmi2/modelDescription.xml", "fmi3/modelDescription.xml", "model_generated.h"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text(), name
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert generation_time().strftime("%Y-%m-%dT%H:%M:%SZ") == "2023-11-14T22:13:20Z"
    generate(model, tmp_path / "c", ["model.c"])
    text = (tmp_path / "c" / "fmi3" / "modelDescription.xml").read_text()
    assert 'generationDateAndTime="2023-11-14T22:13:20Z"' in text and 'copyright="Copyright 2023 ' in text
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(ValueError, match="SOURCE_DATE_EPOCH='yesterday'"):
        generation_time()


def test_licence_is_the_projects_declaration(tmp_path: Path, monkeypatch) -> None:
    from milling_twin.models import codegen

    (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\nlicense = "BSD-3-Clause"\n')
    monkeypatch.setattr(codegen, "REPOSITORY", tmp_path)
    codegen.licence.cache_clear()
    try:
        assert codegen.licence() == "BSD-3-Clause"
        (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\n')
        codegen.licence.cache_clear()
        assert codegen.licence() == codegen.NO_LICENCE
    finally:
        codegen.licence.cache_clear()


def test_static_data_holds_no_infinity_which_msvc_does_not_take_as_a_constant() -> None:
    """INFINITY/NAN are no constant expressions under MSVC 19.42 with the Windows SDK 10.0.26100 (error C2099 in a
    static initializer): the variable tables bound an unbounded side by DBL_MAX, tuple constants refuse non-finite
    values. The MSVC-mode compile of tests/test_cross_platform.py checks the C; this checks the generator."""
    import dataclasses
    import math

    from milling_twin.models import MODELS
    from milling_twin.models.codegen import c_bound, generate_constants, generate_table

    assert (c_bound(-math.inf), c_bound(math.inf), c_bound(0.5)) == ("-DBL_MAX", "DBL_MAX", "0.5")
    with pytest.raises(ValueError, match="NaN"):
        c_bound(math.nan)
    for model in MODELS.values():
        for fmi in (2, 3):
            table = generate_table(model, fmi)
            assert "INFINITY" not in table and "NAN" not in table, (model.identifier, fmi)
            assert "#include <float.h>" in table
    bad = dataclasses.replace(MODELS["SpindlePower"], constants=(("LIMITS", (0.0, math.inf)),))
    with pytest.raises(ValueError, match=r"constant LIMITS: inf in a tuple"):
        generate_constants(bad)
