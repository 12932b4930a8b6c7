"""The pupil-limited relay's fast path (SLM-resolution spectrum, pruned inverse FFT)
against the fine-grid angular-spectrum propagation it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from recon.optics.holo_display import (
    CameraMapping,
    HolographicDisplayModel,
    MaskModel,
    RelayModel,
    SlmModel,
    StagePose,
)


@pytest.mark.parametrize("slm", [SlmModel(), SlmModel(fill_factor=0.8),
                                 SlmModel(fill_factor=0.8, gap_amplitude=0.0)])
@pytest.mark.parametrize("paraxial", [True, False])
@pytest.mark.parametrize("pose", [StagePose(), StagePose(z_mm=0.05),
                                  StagePose(z_mm=-0.03, rx_rad=0.03, ry_rad=-0.02)])
def test_band_relay_equals_the_fine_grid_propagation(slm, paraxial, pose):
    mm = MaskModel((24, 30), 8.0, 4, 2, seed=3)
    sim = HolographicDisplayModel(mm, slm=slm, relay=RelayModel(0.532, na=0.05,
                                                               paraxial=paraxial),
                                  camera=CameraMapping((64, 80)))
    assert sim._band_ok
    phase = np.random.default_rng(0).uniform(-np.pi, np.pi, mm.slm_shape)
    rel = sim._defocus(pose)
    fast = sim._relay_band(phase, rel)
    full = sim._propagate(sim._slm_fine_field(phase), rel)
    assert fast.dtype == np.complex64 and fast.shape == mm.fine_shape
    np.testing.assert_allclose(fast, full, atol=2e-6 * np.abs(full).max())


def test_band_relay_not_used_where_the_field_is_not_pixel_wise_constant():
    mm = MaskModel((24, 30), 8.0, 4, 2, seed=3)
    relay = RelayModel(0.532, na=0.05)
    assert not HolographicDisplayModel(mm, slm=SlmModel(crosstalk_px=0.3), relay=relay)._band_ok
    assert not HolographicDisplayModel(mm, slm=SlmModel(fill_factor=0.8, gap_amplitude=0.5),
                                       relay=relay)._band_ok
    assert not HolographicDisplayModel(mm)._band_ok  # no pupil: nothing to prune
