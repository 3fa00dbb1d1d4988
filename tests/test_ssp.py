"""SSP 1.0 export and import (orchestrator/ssp, docs/ssp.md): the archive follows the SSP 1.0 schemas, a scenario
exported and run again gives the scenario's results bit for bit, libcosim runs an FMI 2 archive within 1e-6 of the
orchestrator, and a broken archive fails naming the file and the element."""
from __future__ import annotations

import dataclasses
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

import milling_twin as mt
from conftest import REPO_ROOT
from milling_twin.cli import main
from milling_twin.orchestrator.scenario import Scenario
from milling_twin.orchestrator.ssp.common import MT_TYPE, SSD_NAME, SspError, q, schema_errors
from milling_twin.orchestrator.ssp.export import export_ssp
from milling_twin.orchestrator.ssp.importer import load_scenario, opened

SCHEMAS = REPO_ROOT / "tests" / "data" / "ssp"  # the standard's XSDs (BSD-2-Clause), not fmpy's copy


def _short(name: str, stop: float, fmu_dir: Path) -> Scenario:
    """A committed scenario stopped early (the tests keep runs short)."""
    scenario = mt.load_scenario(REPO_ROOT / "scenarios" / name, fmu_dir)
    return dataclasses.replace(scenario, stop_time=stop)


def _round_trip(scenario: Scenario, archive: Path) -> tuple[object, object]:
    """The scenario's frame and the frame of its SSP export run again (its [stepping], the hold among it, read
    back as it was)."""
    export_ssp(scenario, archive)
    direct = mt.simulate(scenario).frame
    with opened(archive) as path:
        loaded = mt.load_scenario(path)
        assert loaded.stepping == scenario.stepping
        again = mt.simulate(loaded).frame
    return direct, again


def _fmi2_chatter(tmp_path: Path, delay_force: bool, stop: float = 0.02) -> Path:
    """chatter.toml with the FMI 2 FMUs, stopped at ``stop``; ``delay_force``: force -> vibration delayed too (as
    an importer that steps all FMUs in parallel, libcosim, delays every connection)."""
    text = (REPO_ROOT / "scenarios" / "chatter.toml").read_text()
    text = text.replace('stop_time = 0.2', f'stop_time = {stop}')
    for model in ("CuttingForce", "ToolVibration"):
        text = text.replace(f'fmu = "{model}"', f'fmu = "{model}"\nfmi = 2')
    if delay_force:
        for axis in ("x", "y"):
            text = text.replace(f'to = "vibration.force_{axis}"', f'to = "vibration.force_{axis}"\ndelay = true')
    path = tmp_path / "chatter_fmi2.toml"
    path.write_text(text)
    return path


def _rewrite(source: Path, target: Path, **changes: bytes | None) -> Path:
    """A copy of the archive with members replaced (bytes) or left out (None); keys use "__" for "/"."""
    changes = {name.replace("__", "/").replace("_DOT_", "."): value for name, value in changes.items()}
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for name in zin.namelist():
            if name not in changes:
                zout.writestr(name, zin.read(name))
            elif changes[name] is not None:
                zout.writestr(name, changes[name])
    return target


# ---- the archive ----


def test_the_archive_follows_the_ssp_1_0_schemas_and_names_what_it_cannot_express(fmu_dir: Path,
                                                                                   tmp_path: Path) -> None:
    scenario = _short("chatter.toml", 0.02, fmu_dir)
    result = export_ssp(scenario, tmp_path / "chatter.ssp")
    with zipfile.ZipFile(result.path) as zf:
        names = set(zf.namelist())
        assert names == {SSD_NAME, "resources/CuttingForce.fmu", "resources/ToolVibration.fmu",
                         "resources/force.ssv", "resources/vibration.ssv"}
        ssd = etree.fromstring(zf.read(SSD_NAME))
        assert schema_errors(ssd, "ssd", SCHEMAS) == []
        for member in ("resources/force.ssv", "resources/vibration.ssv"):
            assert schema_errors(etree.fromstring(zf.read(member)), "ssv", SCHEMAS) == []
        force_set = etree.fromstring(zf.read("resources/force.ssv"))
    components = {c.get("name"): c for c in ssd.iter(q("ssd", "Component"))}
    assert list(components) == ["force", "vibration"]
    assert components["force"].get("source") == "resources/CuttingForce.fmu"
    connector = components["force"].find(f".//{q('ssd', 'Connector')}[@name='spindle_speed']")
    assert connector.get("kind") == "input" and connector.find(q("ssc", "Real")).get("unit") == "rad/s"
    speed = force_set.find(f".//{q('ssv', 'Parameter')}[@name='spindle_speed']/{q('ssv', 'Real')}")
    assert float(speed.get("value")) == 6000 * 2 * np.pi / 60 and speed.get("unit") == "rad/s"  # SI, as run
    delayed = [c for c in ssd.iter(q("ssd", "Connection"))
               if c.find(f".//{q('ssc', 'Annotation')}[@type='{MT_TYPE}']") is not None]
    assert [(c.get("startConnector"), c.get("endConnector")) for c in delayed] == [
        ("tip_displacement_x", "displacement_x"), ("tip_displacement_y", "displacement_y")]
    step = components["force"].find(".//{urn:milling-twin:ssp:1}Component")
    assert float(step.get("stepSize")) == 1e-5
    assert any("delay = true" in w for w in result.warnings) and any("FMI 3" in w for w in result.warnings)
    assert result.components == 2 and result.connections == 4


def test_a_whole_part_exports_its_files_arrays_stepping_and_tool_changes(fmu_dir: Path, tmp_path: Path) -> None:
    scenario = _short("al_plate.toml", 0.02, fmu_dir)
    result = export_ssp(scenario, tmp_path / "plate.ssp")
    with zipfile.ZipFile(result.path) as zf:
        names = set(zf.namelist())
        ssd = etree.fromstring(zf.read(SSD_NAME))
    assert schema_errors(ssd, "ssd", SCHEMAS) == []
    assert "resources/files/interp/al_plate.nc" in names
    for what in ("[part]", "[stepping]", "[[on_change]]", "FMI 3 arrays (workpiece.engagement)", "per-FMU step sizes",
                 "file-valued String parameters (interp.program, interp.tool_table)"):
        assert any(w.startswith(what) for w in result.warnings), what
    engagement = ssd.find(f".//{q('ssd', 'Component')}[@name='workpiece']//{q('ssd', 'Connector')}"
                          "[@name='engagement']")
    assert engagement.find(".//{urn:milling-twin:ssp:1}Array").get("shape") == "8,24"


def test_fmpy_reads_the_archive_with_its_parameter_bindings(fmu_dir: Path, tmp_path: Path) -> None:
    """Another reader: FMPy's SSD parser, validating against its copy of the schemas."""
    from fmpy.ssp.ssd import find_components, read_ssd

    archive = export_ssp(_short("chatter.toml", 0.02, fmu_dir), tmp_path / "chatter.ssp").path
    components = {c.name: c for c in find_components(read_ssd(str(archive), validate=True).system)}
    assert list(components) == ["force", "vibration"]
    force_set = components["force"].parameterBindings[0].parameterValues[0]
    assert int({p.name: p.value for p in force_set.parameters}["n_flutes"]) == 2  # FMPy keeps the text


def test_a_calibrated_set_is_bound_through_a_parameter_mapping(fmu_dir: Path, tmp_path: Path) -> None:
    """The scenario's parameter set (the calibration's, names "instance.variable") as an SSV with an SSM per
    component; a value changed in that SSV is the value the archive runs with (it is bound after the component's
    own set)."""
    scenario = _short("calibration/umich_power_calibrated.toml", 0.2, fmu_dir)
    archive = export_ssp(scenario, tmp_path / "calibrated.ssp").path
    with zipfile.ZipFile(archive) as zf:
        values = etree.fromstring(zf.read("resources/sets/umich_power.params.ssv"))
        mapping = etree.fromstring(zf.read("resources/sets/umich_power.params.power.ssm"))
        ssd = zf.read(SSD_NAME).decode()
    assert schema_errors(values, "ssv", SCHEMAS) == [] and schema_errors(mapping, "ssm", SCHEMAS) == []
    entries = {e.get("source"): e.get("target") for e in mapping.iter(q("ssm", "MappingEntry"))}
    assert entries["power.c1"] == "c1" and all(k == f"power.{v}" for k, v in entries.items())
    assert 'source="resources/sets/umich_power.params.power.ssm"' in ssd
    c1 = scenario.instance("power").parameters["c1"]
    text = etree.tostring(values).decode().replace(f'value="{c1!r}"', 'value="0.125"')
    assert "0.125" in text
    changed = _rewrite(archive, tmp_path / "changed.ssp", resources__sets__umich_power_DOT_params_DOT_ssv=text.encode())
    with opened(changed) as path:
        assert mt.load_scenario(path).instance("power").parameters["c1"] == 0.125


# ---- scenario -> SSP -> run = scenario run ----


@pytest.mark.parametrize("name, stop", [("chatter.toml", 0.05), ("slot_milling.toml", 0.02),
                                        ("slot_entry_variable.toml", 0.2), ("umich_power.toml", 0.2),
                                        ("chatter_forcenet.toml", 0.02), ("al_plate.toml", 0.2),
                                        ("calibration/umich_power_calibrated.toml", 0.2)])
def test_the_archive_runs_as_the_scenario_bit_for_bit(name: str, stop: float, fmu_dir: Path, tmp_path: Path) -> None:
    """Delays, step sizes, [stepping], recorded inputs, FMI 3 arrays, a tool change: all restored from the
    annotations, so every column is identical."""
    direct, again = _round_trip(_short(name, stop, fmu_dir), tmp_path / "twin.ssp")
    assert list(again.columns) == list(direct.columns) and len(direct) > 1
    assert direct.equals(again)


def test_a_whole_part_from_the_archive_has_its_part_and_process_report(fmu_dir: Path, tmp_path: Path) -> None:
    scenario = _short("al_plate.toml", 0.2, fmu_dir)
    archive = export_ssp(scenario, tmp_path / "plate.ssp").path
    direct = mt.simulate(scenario, out=tmp_path / "toml")
    with opened(archive) as path:
        loaded = load_scenario(path)
        assert loaded.part.program.parent == path.parent / "resources" / "files" / "interp"
        assert dataclasses.replace(loaded.part, program=scenario.part.program,
                                   tool_table=scenario.part.tool_table) == scenario.part
        again = mt.simulate(loaded, out=tmp_path / "ssp")
    assert again.frame.equals(direct.frame)
    first, second = direct.process_report, again.process_report
    assert second is not None and second.html.is_file()
    assert (second.machining_time, second.blocks, second.max_force, second.removed_volume) == \
        (first.machining_time, first.blocks, first.max_force, first.removed_volume)


def test_the_cli_exports_and_runs_the_archive(fmu_dir: Path, tmp_path: Path, capsys) -> None:
    scenario = _fmi2_chatter(tmp_path, delay_force=False)
    archive = tmp_path / "twin.ssp"
    fmu = ["--fmu-dir", str(fmu_dir)]
    assert main(["export-ssp", str(scenario), "-o", str(archive), *fmu, "--set", "force.axial_depth=0.04mm"]) == 0
    out, err = capsys.readouterr()
    assert f"wrote {archive}: 2 components, 4 connections" in out
    assert "warning: SSP 1.0 cannot express delay = true" in err
    assert main(["run", str(archive), "--out", str(tmp_path / "ssp"), "--no-progress", *fmu]) == 0
    assert main(["run", str(scenario), "--out", str(tmp_path / "toml"), "--no-progress", *fmu,
                 "--set", "force.axial_depth=0.04mm"]) == 0
    assert mt.load_results(tmp_path / "ssp" / "chatter").equals(mt.load_results(tmp_path / "toml" / "chatter"))


# ---- the same archive in libcosim ----


def _libcosim_rows(archive: Path, names: dict[str, list[str]], steps: int) -> np.ndarray:
    """The outputs ``names`` (by component) after each of ``steps`` steps of libcosim running the archive."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.FATAL)
    execution = CosimExecution.from_ssp_file(str(archive))  # the archive itself: libcosim unpacks it
    observer = CosimObserver.create_last_value()
    assert execution.add_observer(observer)
    index = {s.name.decode(): s.index for s in execution.slave_infos()}
    refs = {c: {v.name.decode(): v.reference for v in execution.slave_variables(index[c])} for c in names}
    rows = []
    for _ in range(steps):
        assert execution.step(1), execution.status()
        rows.append([observer.last_real_values(index[c], [refs[c][n]])[0] for c, ns in names.items() for n in ns])
    return np.array(rows)


def test_libcosim_runs_the_fmi2_archive_within_1e_6_of_the_orchestrator(fmu_dir: Path, tmp_path: Path) -> None:
    """libcosim steps all FMUs in parallel (every connection delayed), so the case SSP 1.0 expresses has every
    connection delayed; its base step and per-component steps come from the osp annotations."""
    scenario = mt.load_scenario(_fmi2_chatter(tmp_path, delay_force=True), fmu_dir)
    archive = export_ssp(scenario, tmp_path / "twin.ssp").path
    with opened(archive) as path:
        frame = mt.simulate(mt.load_scenario(path)).frame
    names = {"force": ["Fx", "Fy"], "vibration": ["tip_displacement_x", "tip_displacement_y"]}
    columns = [f"{c}.{n}" for c, ns in names.items() for n in ns]
    ours = frame[columns].to_numpy()[1:]  # the rows after each step (libcosim has none at t = 0)
    theirs = _libcosim_rows(archive, names, len(ours))
    assert np.abs(ours[:, :2]).max() > 0.5  # forces of ~1 N, displacements of ~0.6 um
    assert np.abs(theirs - ours).max() <= 1e-6 * np.abs(ours).max(axis=0).max()
    assert np.abs(theirs[:, :2] - ours[:, :2]).max() <= 1e-6


def test_an_archive_without_the_projects_annotations_runs_as_libcosim_runs_it(fmu_dir: Path, tmp_path: Path) -> None:
    """Another tool's SSD: steps from libcosim's osp annotations, every connection delayed, every output recorded,
    the output interval the base step; the FMI 2 chatter with every connection delayed gives the same values."""
    scenario = mt.load_scenario(_fmi2_chatter(tmp_path, delay_force=True), fmu_dir)
    archive = export_ssp(scenario, tmp_path / "twin.ssp").path
    ssd = etree.fromstring(_ssd(archive).encode())
    for item in list(ssd.iter(q("ssc", "Annotation"))):
        if item.get("type") == MT_TYPE:
            item.getparent().remove(item)
    for holder in list(ssd.iter(q("ssd", "Annotations"))):
        if len(holder) == 0:
            holder.getparent().remove(holder)
    assert schema_errors(ssd, "ssd", SCHEMAS) == []
    foreign = _rewrite(archive, tmp_path / "foreign.ssp", SystemStructure_DOT_ssd=etree.tostring(ssd))
    with opened(foreign) as path:
        loaded = mt.load_scenario(path)
        frame = mt.simulate(loaded).frame
    assert [i.step_size for i in loaded.instances] == [1e-5, 1e-5] and loaded.output_interval == 1e-5
    assert all(c.delay for c in loaded.connections) and len(frame.columns) > 5
    reference = mt.simulate(scenario).frame
    assert frame[reference.columns].equals(reference)


def test_libcosim_refuses_fmi3_components(fmu_dir: Path, tmp_path: Path) -> None:
    """A known limit of libcosim (documented in docs/ssp.md): no FMI 3; the error says so."""
    from libcosimpy._internal import get_last_error_message
    from libcosimpy.CosimExecution import CosimExecution

    archive = export_ssp(_short("chatter.toml", 0.02, fmu_dir), tmp_path / "fmi3.ssp").path
    with pytest.raises(AssertionError):
        CosimExecution.from_ssp_file(str(archive))
    assert "Unsupported FMI version" in get_last_error_message()


# ---- broken archives ----


@pytest.fixture
def archive(fmu_dir: Path, tmp_path: Path) -> Path:
    return export_ssp(_short("chatter.toml", 0.02, fmu_dir), tmp_path / "good.ssp").path


def _ssd(archive: Path) -> str:
    with zipfile.ZipFile(archive) as zf:
        return zf.read(SSD_NAME).decode()


def _error(path: Path) -> str:
    with pytest.raises(SspError) as info:
        with opened(path) as scenario:
            mt.load_scenario(scenario)
    return str(info.value)


def test_a_missing_fmu_names_the_component_and_the_file(archive: Path, tmp_path: Path) -> None:
    broken = _rewrite(archive, tmp_path / "bad.ssp", resources__ToolVibration_DOT_fmu=None)
    message = _error(broken)
    assert message.startswith(f"{broken}: {SSD_NAME}: line ")
    assert '<ssd:Component name="vibration" source="resources/ToolVibration.fmu">' in message
    assert "resources/ToolVibration.fmu is not in the archive (files of its kind: resources/CuttingForce.fmu)" \
        in message


def test_an_unknown_connector_names_the_connection(archive: Path, tmp_path: Path) -> None:
    text = _ssd(archive).replace('endConnector="force_x"', 'endConnector="force_q"')
    message = _error(_rewrite(archive, tmp_path / "bad.ssp", SystemStructure_DOT_ssd=text.encode()))
    assert re.search(r'SystemStructure.ssd: line \d+: <ssd:Connection startElement="force" startConnector="Fx" '
                     r'endElement="vibration" endConnector="force_q">: no connector \'force_q\' in component '
                     r"'vibration'; its connectors: ", message), message


def test_an_unknown_parameter_names_the_parameter_set_and_the_parameter(archive: Path, tmp_path: Path) -> None:
    with zipfile.ZipFile(archive) as zf:
        text = zf.read("resources/force.ssv").decode().replace('name="n_flutes"', 'name="n_flute"')
    message = _error(_rewrite(archive, tmp_path / "bad.ssp", resources__force_DOT_ssv=text.encode()))
    assert re.search(r"resources/force.ssv: line \d+: <ssv:Parameter name=\"n_flute\">: no connector 'n_flute' in "
                     r"component 'force'", message), message


def test_invalid_xml_and_a_schema_violation_name_the_file_and_line(archive: Path, tmp_path: Path) -> None:
    text = _ssd(archive)
    message = _error(_rewrite(archive, tmp_path / "cut.ssp", SystemStructure_DOT_ssd=text[:2000].encode()))
    assert f"cut.ssp: {SSD_NAME}: invalid XML: " in message and "line" in message
    text = text.replace('kind="parameter"', 'kind="parametre"', 1)
    message = _error(_rewrite(archive, tmp_path / "xsd.ssp", SystemStructure_DOT_ssd=text.encode()))
    assert f"xsd.ssp: {SSD_NAME}: does not follow the SSP 1.0 schema: line " in message
    assert "Connector" in message and "parametre" in message


def test_the_run_command_fails_with_exit_code_2_naming_the_archive(tmp_path: Path, capsys) -> None:
    not_zip = tmp_path / "twin.ssp"
    not_zip.write_text("no zip")
    assert main(["run", str(not_zip), "--no-progress"]) == 2
    assert f"error: {not_zip}: not an SSP archive (a zip file)" in capsys.readouterr().err
