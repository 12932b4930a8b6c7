"""The prior chosen by held-out cross-validation (recon.auto.prior), the prior on the
front door, the command line and another array-API backend."""

from __future__ import annotations

import json

import numpy as np
import pytest

import recon
from instrument.cli import main
from recon.auto import ChannelProblem, solve_channel
from recon.auto.prior import PRIOR_RULES, choose_prior
from recon.auto.weight import AutoWeight
from recon.errors import DivergenceError, ReconInputError
from recon.operators import ConvolutionOperator
from recon.options import ReconOptions
from recon.solvers import admm
from recon.solvers.common import History


def _weight(w: float, err: float, se: float) -> AutoWeight:
    return AutoWeight(w, "holdout", "", 0.0, path=[
        {"weight": w * 2, "holdout_error": err + 1.0, "standard_error": se},
        {"weight": w, "holdout_error": err, "standard_error": se}], path_iterations=10)


class _Res:
    def __init__(self):
        self.params = {}
        self.x = np.zeros(1)


def _paths(scores: dict):
    """A stand-in for prior_path: each prior's (weight, error, se) or an exception."""
    seen = []

    def path(name, rule):
        seen.append((name, rule))
        v = scores[name]
        if isinstance(v, Exception):
            raise v
        return _Res(), _weight(*v)

    return path, seen


def test_the_simplest_prior_within_one_standard_error_of_the_best_is_chosen():
    path, seen = _paths({"tv": (1e-4, 0.50, 0.02), "wavelet": (1e-4, 0.49, 0.02),
                         "dncnn": (0.1, 0.47, 0.02)})
    res, weight, choice = choose_prior(path)
    assert [s[0] for s in seen] == ["tv", "wavelet", "dncnn"]
    assert [s[1] for s in seen] == [PRIOR_RULES[p] for p in ("tv", "wavelet", "dncnn")]
    # best dncnn 0.47 +- 0.02: the limit 0.49 takes wavelet (tv 0.50 is above it)
    assert choice.prior == "wavelet" and weight.regulariser == "wavelet"
    assert "simplest prior within 1 standard error" in choice.reason
    assert res.params["prior"]["prior"] == "wavelet"
    assert [c["holdout_error"] for c in choice.candidates] == [0.50, 0.49, 0.47]
    assert set(choice.results) == {"tv", "wavelet", "dncnn"}
    d = choice.as_dict()
    assert d["prior"] == "wavelet" and "results" not in d
    json.dumps(d)


def test_a_clearly_better_prior_is_taken_and_a_diverged_one_recorded():
    path, _ = _paths({"tv": (1e-4, 0.60, 0.01),
                      "wavelet": DivergenceError("diverged", History(), None),
                      "dncnn": (0.1, 0.45, 0.01)})
    _, _, choice = choose_prior(path)
    assert choice.prior == "dncnn" and "dncnn predicts the held-out pixels best" in choice.reason
    assert "failed: wavelet" in choice.reason
    assert "error" in choice.candidates[1]


def test_no_finished_prior_is_an_error_naming_each():
    err = DivergenceError("boom", History(), None)
    path, _ = _paths({"tv": err, "wavelet": err, "dncnn": err})
    with pytest.raises(ReconInputError, match="tv: boom.*dncnn: boom"):
        choose_prior(path)


@pytest.fixture(scope="module")
def case():
    """A small camera scene through a random caustic, Poisson noise (raw counts)."""
    from skimage import data

    rng = np.random.default_rng(5)
    psf = rng.random((40, 56)) ** 12
    scene = np.zeros((40, 56))
    scene[8:32, 12:44] = data.camera()[::21, ::16][:24, :32] / 255.0
    raw = np.real(np.fft.ifft2(np.fft.fft2(scene) * np.fft.fft2(np.fft.ifftshift(psf))))
    raw = rng.poisson(np.clip(raw, 0, None) / raw.max() * 2000).astype(np.float64)
    return psf.astype(np.float32) * 1000, raw


@pytest.mark.parametrize("method", ["wiener", "gd", "fista"])
def test_a_prior_with_a_method_that_takes_none_is_refused_before_any_work(case, method):
    """The declaration's check between ``prior`` and ``method``, shared by
    :func:`recon.reconstruct` and the forms and flags generated from ReconOptions.
    Before: Wiener ran without the prior, silently; GD and FISTA refused it only inside
    the solve, after the data were prepared."""
    from diffuserlab.errors import InputError

    psf, raw = case
    with pytest.raises(ReconInputError, match=f"prior='dncnn': method='{method}' takes no "
                       "image prior.*method='admm'"):
        recon.reconstruct(psf, raw, method, prior="dncnn", tv=1e-3, iterations=5,
                          dark="none")
    with pytest.raises(InputError, match=f"--prior wavelet: --method {method} takes no"):
        ReconOptions.from_text({"--method": method, "--prior": "wavelet"})  # a GUI form
    assert ReconOptions.validated({"method": method, "prior": "tv"}).prior == "tv"


def test_solve_channel_refuses_what_a_prior_cannot_do(case):
    op = ConvolutionOperator(case[0] / case[0].sum())
    raw = case[1].astype(np.float32)
    b = raw / raw.max()
    problem = ChannelProblem(op, b, raw, raw.max())

    def options(**values):  # what a library call passes (not validated: the solve checks)
        return ReconOptions.from_defaults(**{"iterations": 5, "l1": 0.0, **values})

    with pytest.raises(ReconInputError, match="prior auto chooses each prior's weight"):
        solve_channel(problem, options(method="admm", tv=1e-4, prior="auto"))
    with pytest.raises(ReconInputError, match="the wavelet prior runs in ADMM"):
        solve_channel(problem, options(method="fista", tv=1e-4, prior="wavelet"))
    with pytest.raises(ReconInputError, match="use one of tv, tv-iso, tgv, wavelet, dncnn"):
        solve_channel(problem, options(method="admm", tv=1e-4, prior="bm3d"))
    with pytest.raises(ReconInputError, match="automatic l1 weight is chosen with TV only"):
        solve_channel(problem, options(method="admm", tv=1e-4, prior="wavelet", l1="auto"))
    res, rec = solve_channel(problem, options(method="wiener", tv=0.0, prior="wavelet"))
    assert rec["prior"] == {"prior": None, "reason": "wiener has no prior"}


def test_front_door_with_a_fixed_and_an_automatic_prior(case):
    psf, raw = case
    fixed = recon.reconstruct(psf, raw, "admm", tv=1e-3, prior="wavelet", iterations=20,
                              dark="none")
    assert fixed.info["prior"] == "wavelet" and fixed.info.tv == 1e-3
    assert fixed.results[0].params["prior"]["wavelet"] == "sym4"
    chosen = recon.reconstruct(psf, raw, "admm", prior="auto", iterations=20, dark="none")
    rec = chosen.info.auto[0]
    assert chosen.info["prior"] == rec["prior"]["prior"] in ("tv", "wavelet", "dncnn")
    assert [c["prior"] for c in rec["prior"]["candidates"]] == ["tv", "wavelet", "dncnn"]
    assert rec["weight"]["regulariser"] == rec["prior"]["prior"]
    assert chosen.info.tv == rec["weight"]["weight"]
    # the chosen prior's own path gives the same image (the choice adds nothing else)
    again = recon.reconstruct(psf, raw, "admm", prior=rec["prior"]["prior"], iterations=20,
                              dark="none")
    np.testing.assert_allclose(again.image, chosen.image, rtol=1e-5, atol=1e-6)
    with pytest.raises(ReconInputError, match="prior"):
        recon.reconstruct(psf, raw, "admm", prior="nonsense", dark="none")


def test_cli_recon_takes_the_prior_and_records_it(case, tmp_path, capsys):
    psf, raw = case
    np.save(tmp_path / "psf.npy", psf)
    np.save(tmp_path / "raw.npy", raw)
    js = tmp_path / "m.json"
    rc = main(["recon", "--psf", str(tmp_path / "psf.npy"), "--raw", str(tmp_path / "raw.npy"),
               "--method", "admm", "--tv", "0.001", "--prior", "dncnn", "--iterations", "10",
               "--dark", "none", "--out", str(tmp_path / "o.png"), "--metrics-json", str(js)])
    assert rc == 0
    m = json.loads(js.read_text())
    assert m["prior"] == "dncnn" and m["params"][0]["prior"]["model"] == "dncnn.onnx"
    with pytest.raises(SystemExit) as exc:
        main(["recon", "--psf", str(tmp_path / "psf.npy"), "--raw", str(tmp_path / "raw.npy"),
              "--prior", "bm3d"])
    assert exc.value.code == 2
    assert "--prior" in capsys.readouterr().err


def test_a_prior_runs_on_another_array_api_backend(case):
    """The generic kernel set on array-api-strict (a stand-in for a GPU's arrays): the
    same result as on NumPy."""
    xs = pytest.importorskip("array_api_strict")
    op = ConvolutionOperator(case[0] / case[0].sum())
    b = (case[1] / case[1].max()).astype(np.float32)
    host = admm(op, b, iterations=15, tv=1e-3, prior="wavelet")
    dev = admm(op, xs.asarray(b), iterations=15, tv=1e-3, prior="wavelet")
    assert not isinstance(dev.x, np.ndarray)
    np.testing.assert_allclose(np.asarray(dev.x), host.x, rtol=1e-4,
                               atol=1e-5 * float(host.x.max()))


def test_a_volume_takes_a_named_prior_with_a_fixed_weight(case):
    psf, raw = case
    stack = recon.PsfStack(np.stack([psf, np.roll(psf, 4, axis=1)]), [10.0, 12.0])
    vol = recon.reconstruct(stack, raw, "admm", tv=1e-3, prior="wavelet", iterations=10,
                            dark="none")
    assert vol.info["prior"] == "wavelet"
    assert vol.results[0].params["prior"]["prior"] == "wavelet"
    assert vol.metrics(1.0)["prior"] == "wavelet"
    tv3d = recon.reconstruct(stack, raw, "admm", tv=1e-3, iterations=5, dark="none")
    assert tv3d.info["prior"] == "tv"
    for kwargs, words in (({"prior": "auto", "tv": 1e-3}, "a volume takes one named prior"),
                          ({"prior": "dncnn", "tv": "auto"}, "chosen with 3D TV"),
                          ({"prior": "dncnn", "tv": 1e-3, "method": "fista"},
                           "method=.fista. takes no image prior")):
        kw = {"method": "admm", **kwargs}
        with pytest.raises(ReconInputError, match=words):
            recon.reconstruct(stack, raw, kw.pop("method"), iterations=5, dark="none", **kw)
