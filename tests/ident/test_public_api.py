"""``__all__`` of the identification, filter and data-file packages lists exactly what they export."""

import types

import pytest

import hilident.datafile
import hilident.filters
import hilident.ident
import hilident.ident.tffit


@pytest.mark.parametrize("package", [hilident.ident, hilident.ident.tffit, hilident.filters, hilident.datafile])
def test_all_lists_every_public_name_and_nothing_else(package):
    public = {
        name
        for name, value in vars(package).items()
        if not name.startswith("_") and not isinstance(value, types.ModuleType)
    }
    assert sorted(package.__all__) == sorted(public)
    assert len(set(package.__all__)) == len(package.__all__)


def test_ident_exports_what_it_did_before_tffit_became_a_package():
    drift = {"DriftTrend", "SeriesTrend", "axis_drifts", "drift_trend"}  # added since, by hilident.ident.drift
    assert drift <= set(hilident.ident.__all__)
    assert len(hilident.ident.__all__) == 85 + len(drift)
    assert hilident.ident.select_tf_order is hilident.ident.tffit.select_order
    assert hilident.ident.select_order is not hilident.ident.select_tf_order  # the ODE order search
