"""One home for each default: every option of the localizer, the estimator and the master takes its default
from its settings field, and every field made from a core's field (``from_core``) takes the core's default
and bound; the settings modules write no default of their own into an option."""

from __future__ import annotations

import ast
import enum
import importlib
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from common.bounds import field_bounds, field_default
from common.estimation.coupling_types import CouplingSettings
from common.localization.scoring import ParticleSettings, ScoringSettings
from common.localization.tracker_state import TrackerSettings
from common.streams import FrameGateSettings
from common.yaw import YawSettings
from services.estimator.settings import EstimatorSettings
from services.estimator.settings import settings_from_args as estimator_from_args
from services.localizer.settings import LocalizerSettings
from services.localizer.settings import settings_from_args as localizer_from_args
from services.master.lens import YawPriorSettings
from services.master.settings import MasterSettings, master_settings_from_args
from services.runtime.cli import StreamBoundSettings
from services.runtime.fields import settings_from
from services.runtime.mount_options import MountOptions
from services.runtime.options import core_origin
from services.tools.cli import build_parser
from services.worker.service import WorkerSettings

ROOT = Path(__file__).resolve().parents[2]
COMMANDS: dict[str, tuple[type[BaseModel], Any]] = {
    "localizer": (LocalizerSettings, localizer_from_args),
    "estimator": (EstimatorSettings, estimator_from_args),
    "master": (MasterSettings, master_settings_from_args),
    "worker": (WorkerSettings, lambda args: settings_from(WorkerSettings, args)),
}
#: the settings of the master's nested parts whose fields are options too
NESTED: dict[str, tuple[type[BaseModel], ...]] = {
    "master": (YawPriorSettings, MountOptions),
    "estimator": (MountOptions,),
}
SETTINGS_MODULES = [
    "services/localizer/settings.py",
    "services/estimator/settings.py",
    "services/master/settings.py",
    "services/master/lens.py",
    "services/runtime/camera_options.py",
    "services/runtime/mount_options.py",
    "services/worker/service.py",
    "services/foreman/service.py",
]


def _core(path: str) -> tuple[type[Any], str]:
    module, cls, name = path.rsplit(".", 2)
    return getattr(importlib.import_module(module), cls), name


def _wire(value: Any) -> Any:
    return value.value if isinstance(value, enum.Enum) else value


def _models(command: str) -> tuple[type[BaseModel], ...]:
    return (COMMANDS[command][0], *NESTED.get(command, ()))


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_default_is_its_field_default(command: str) -> None:
    args = vars(build_parser().parse_args([command]))
    checked = 0
    for model in _models(command):
        for name, info in model.model_fields.items():
            if name in args:
                default = info.get_default(call_default_factory=True)
                assert _wire(args[name]) == _wire(default), f"{command} --{name}: option and field differ"
                checked += 1
    assert checked >= 4  # the options are generated from the fields (not a vacuous loop)


@pytest.mark.parametrize("command", ["worker", "foreman"])
def test_the_stream_bound_options_default_to_their_fields(command: str) -> None:
    args = build_parser().parse_args([command])
    assert (args.max_streams, args.stream_ttl_s) == (
        StreamBoundSettings().max_streams,
        StreamBoundSettings().stream_ttl_s,
    )


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_the_command_line_without_options_gives_the_default_settings(command: str) -> None:
    model, from_args = COMMANDS[command]
    assert from_args(build_parser().parse_args([command])) == model()


@pytest.mark.parametrize("command", ["localizer", "estimator", "master"])
def test_every_field_from_a_core_has_the_core_default_and_bounds(command: str) -> None:
    found = 0
    for model in _models(command):
        for name, info in model.model_fields.items():
            origin = core_origin(info)
            if origin is None:
                continue
            found += 1
            path, unit = origin
            cls, core_name = _core(path)
            core_default = field_default(cls, core_name)
            shown = (
                unit.shown(core_default) if unit is not None and core_default is not None else core_default
            )
            assert info.default == shown, f"{model.__name__}.{name} != {path}"
            if unit is not None and core_default is not None:
                assert unit.core(info.default) == pytest.approx(core_default, rel=1e-12)
            limits = field_bounds(cls).get(core_name)
            declared = {
                k: getattr(m, k) for m in info.metadata for k in ("gt", "ge", "lt", "le") if hasattr(m, k)
            }
            expected = {} if limits is None else {
                k: getattr(limits, k) for k in ("gt", "ge", "lt", "le") if getattr(limits, k) is not None
            }  # fmt: skip
            for key, value in expected.items():
                assert declared.get(key) == pytest.approx(unit.shown(value) if unit else value), (
                    f"{model.__name__}.{name}: bound {key} differs from {path}"
                )
    assert found > 0


def test_the_particles_the_yaw_rate_limit_and_the_coupling_come_from_their_cores() -> None:
    expected: dict[tuple[type[BaseModel], str], str] = {
        (LocalizerSettings, "particles"): "common.localization.scoring.ParticleSettings.n_particles",
        (YawPriorSettings, "max_yaw_rate_deg_s"): "common.yaw.settings.YawSettings.max_yaw_rate_deg_s",
        (MasterSettings, "max_seq_jump"): "common.streams.FrameGateSettings.max_seq_jump",
        (EstimatorSettings, "max_lag_s"): "common.estimation.coupling_types.CouplingSettings.max_lag_s",
    }
    for (model, name), path in expected.items():
        origin = core_origin(model.model_fields[name])
        assert origin is not None and origin[0] == path


def _literal_defaults(path: Path) -> list[str]:
    """``add_argument(..., default=<number literal>)`` calls: a default written beside its field's."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            for keyword in node.keywords:
                value = keyword.value
                if isinstance(value, ast.UnaryOp):
                    value = value.operand
                number = isinstance(value, ast.Constant) and type(value.value) in (int, float)
                if keyword.arg == "default" and number:
                    found.append(f"{path.name}:{node.lineno}")
    return found


@pytest.mark.parametrize("module", SETTINGS_MODULES)
def test_no_option_writes_its_default_as_a_literal(module: str) -> None:
    assert _literal_defaults(ROOT / module) == []


def test_the_literal_check_finds_a_literal_default(tmp_path: Path) -> None:
    path = tmp_path / "m.py"
    path.write_text(
        'p.add_argument("--particles", type=int, default=200)\np.add_argument("--x", default=-1.5)\n'
    )
    assert _literal_defaults(path) == ["m.py:1", "m.py:2"]


def test_a_generated_option_parses_its_type_and_choices() -> None:
    args = build_parser().parse_args(
        ["estimator", "--no-rectify", "--filter", "paper_c", "--initial-xy", "1", "2", "--max-lag", "0.1"]
    )
    settings = estimator_from_args(args)
    assert (settings.rectify, settings.filter.value, settings.initial_position_m) == (
        False,
        "paper_c",
        (1.0, 2.0),
    )
    assert settings.coupling().max_lag_s == 0.1 and settings.coupling().initial_position_m == (1.0, 2.0)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["estimator", "--filter", "kalman"])
    assert isinstance(build_parser().parse_args(["localizer", "--particles", "50"]).particles, int)


def test_the_default_service_settings_give_the_default_core_settings() -> None:
    """The service's defaults (in degrees where the core has radians) go back to the core's exactly."""
    assert LocalizerSettings().tracker_settings() == TrackerSettings()
    particle = LocalizerSettings().particle_filter_settings()
    assert (particle.n_particles, particle.scoring) == (ParticleSettings().n_particles, ScoringSettings())
    assert EstimatorSettings().coupling() == CouplingSettings()
    assert MasterSettings().gate_settings() == FrameGateSettings()
    assert MasterSettings().prior.max_yaw_rate_deg_s == YawSettings().max_yaw_rate_deg_s
