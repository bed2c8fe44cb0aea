"""The estimator service's vehicle setting: ``any`` by default, ``--vehicle`` selects the model (the model
itself is tested in tests/common/estimation/test_vehicle.py)."""

from __future__ import annotations

import argparse

import pytest

from common.estimation.coupling_types import CouplingSettings, Vehicle, vehicle_settings
from services.estimator.settings import EstimatorSettings, add_estimator_arguments, settings_from_args


def test_the_service_assumes_any_vehicle_by_default() -> None:
    assert EstimatorSettings().vehicle is Vehicle.ANY
    assert EstimatorSettings().coupling() == CouplingSettings()


def test_the_still_air_multirotor_setting_gives_the_models_coupling_settings() -> None:
    settings = CouplingSettings(**vehicle_settings(Vehicle.STILL_AIR_MULTIROTOR))
    assert EstimatorSettings(vehicle=Vehicle.STILL_AIR_MULTIROTOR).coupling() == settings


@pytest.mark.parametrize("value", [member.value for member in Vehicle])
def test_the_service_option_selects_the_vehicle(value: str) -> None:
    parser = argparse.ArgumentParser()
    add_estimator_arguments(parser)
    assert settings_from_args(parser.parse_args(["--vehicle", value])).vehicle is Vehicle(value)
    with pytest.raises(SystemExit):
        parser.parse_args(["--vehicle", "boat"])
