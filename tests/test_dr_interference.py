"""The interference model I(n, d): fit with a grid search, predict, the on-line window of 120, the model file
(versioned JSON, refit on load) and bad files (one InputError line; random, truncated and bit-flipped files)."""
from __future__ import annotations

import json
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.dr.interference import FORMAT, UNITS, WINDOW, ZERO, InterferenceModel
from runtime.errors import InputError

DISTANCES = (1.0, 1.4, 1.8, 2.5, 2.8, 3.3, 3.6, 4.0, 5.0, 6.5)


def synthetic(noise: float = 0.0, seed: int = 0) -> list[tuple[float, float, float]]:
    """80 samples like Fig. 2: I grows with n, shrinks with d (wu/s)."""
    rnd = random.Random(seed)
    return [(float(n), d, 0.06 * (n - 1) ** 1.3 / d + rnd.gauss(0, noise)) for d in DISTANCES for n in range(1, 9)]


def truth(n, d):
    return 0.06 * (n - 1) ** 1.3 / d


@pytest.fixture(scope="module")
def fitted():
    return InterferenceModel.from_samples(synthetic(0.005), search=True, source="synthetic test samples")


def test_fit_predicts_the_trend_and_interpolates(fitted):
    assert len(fitted.samples) == 80 and fitted.source == "synthetic test samples"
    assert fitted.C > 0 and fitted.gamma > 0
    for n, d in [(8, 1.4), (4, 2.0), (2.5, 3.0), (6, 4.5)]:
        assert fitted.predict(n, d) == pytest.approx(truth(n, d), abs=0.03)
    assert fitted.predict(8, 1.4) > fitted.predict(4, 1.4) > fitted.predict(2, 1.4)
    assert fitted.predict(8, 1.4) > fitted.predict(8, 4.0)


def test_a_grid_search_beats_a_flat_fit():
    samples = synthetic(0.0)
    searched = InterferenceModel.from_samples(samples, search=True)
    flat = InterferenceModel(samples, C=0.1, gamma=0.1)
    err = lambda m: sum((m.predict(n, d) - i) ** 2 for n, d, i in samples)   # noqa: E731
    assert err(searched) < err(flat)


def test_add_keeps_the_newest_120_dropping_the_oldest_first(fitted):
    m = fitted.copy()
    first = list(m.samples)
    for k in range(WINDOW - 80):
        m.add(3.0, 2.0, 0.1)
    assert len(m.samples) == WINDOW and m.samples[0] == first[0]
    m.add(3.5, 2.0, 0.4)
    assert len(m.samples) == WINDOW and m.samples[0] == first[1] and m.samples[-1] == (3.5, 2.0, 0.4)
    assert fitted.samples == first                      # the copy learnt alone
    assert (m.C, m.gamma) == (fitted.C, fitted.gamma)   # on-line refits keep the chosen hyperparameters


def test_online_samples_move_the_prediction(fitted):
    m = fitted.copy()
    before = m.predict(3.0, 2.0)
    for _ in range(40):
        m.add(3.0, 2.0, before + 0.5)
    assert m.predict(3.0, 2.0) > before + 0.3


def test_zero_is_no_interference_and_learns_nothing():
    assert ZERO.predict(8, 1.0) == 0.0 and ZERO.samples == []
    ZERO.add(3, 2.0, 1.0)
    assert ZERO.predict(3, 2.0) == 0.0 and ZERO.samples == []
    assert InterferenceModel().predict(2, 2.0) == 0.0            # no samples yet


def test_save_and_load_round_trip(tmp_path, fitted):
    path = tmp_path / "model.json"
    fitted.save(path)
    data = json.loads(path.read_text())
    assert data["format"] == FORMAT and data["version"] == 1 and data["units"] == UNITS
    assert data["source"] == "synthetic test samples" and len(data["samples"]) == 80
    again = InterferenceModel.load(path)
    assert again.samples == fitted.samples and (again.C, again.gamma) == (fitted.C, fitted.gamma)
    for n, d in [(1, 1.0), (5.5, 2.2), (8, 6.5)]:
        assert again.predict(n, d) == pytest.approx(fitted.predict(n, d), abs=1e-9)


def _good(tmp_path, fitted) -> bytes:
    path = tmp_path / "good.json"
    fitted.save(path)
    return path.read_bytes()


@pytest.mark.parametrize("change, key", [
    (lambda d: d.update(format="other"), "format"),
    (lambda d: d.update(version=2), "version"),
    (lambda d: d["units"].update(d="du"), "units"),
    (lambda d: d["hyperparameters"].update(C=0), "hyperparameters.C"),
    (lambda d: d["hyperparameters"].pop("gamma"), "hyperparameters.gamma"),
    (lambda d: d["samples"].__setitem__(3, [1, 2]), "samples[3]"),
    (lambda d: d["samples"].__setitem__(5, [0, 2, 0.1]), "samples[5]"),
    (lambda d: d["samples"].__setitem__(7, [1, 2, "x"]), "samples[7]"),
    (lambda d: d.update(samples={}), "samples"),
    (lambda d: d.update(window=0), "window"),
])
def test_bad_files_are_one_line_naming_file_and_key(tmp_path, fitted, change, key):
    data = json.loads(_good(tmp_path, fitted))
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError) as exc:
        InterferenceModel.load(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(str(path)) and key in msg


def test_missing_and_non_json_files(tmp_path):
    for path, text in [(tmp_path / "none.json", None), (tmp_path / "x.json", "not json {")]:
        if text is not None:
            path.write_text(text)
        with pytest.raises(InputError, match=str(path)):
            InterferenceModel.load(path)


def _load_or_input_error(tmp_path, data: bytes) -> None:
    path = tmp_path / "fuzz.json"
    path.write_bytes(data)
    try:
        m = InterferenceModel.load(path)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert all(math.isfinite(v) for s in m.samples for v in s)
    assert math.isfinite(m.predict(2.0, 2.0))


_GOOD: bytes | None = None


def good_bytes() -> bytes:
    global _GOOD
    if _GOOD is None:
        m = InterferenceModel(synthetic()[:12], C=10, gamma=1, source="fuzz")
        _GOOD = (json.dumps(m.to_json()) + "\n").encode()
    return _GOOD


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400))
def test_random_files_load_or_raise_input_error(tmp_path_factory, data):
    _load_or_input_error(tmp_path_factory.mktemp("r"), data)


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 10_000), st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 7)), max_size=8))
def test_truncated_and_bit_flipped_files_load_or_raise_input_error(tmp_path_factory, cut, flips):
    data = bytearray(good_bytes())
    for pos, bit in flips:
        data[pos % len(data)] ^= 1 << bit
    _load_or_input_error(tmp_path_factory.mktemp("f"), bytes(data[:cut % (len(data) + 1)]))


def test_models_with_the_same_samples_share_one_fit_and_predict_as_a_fresh_fit():
    """A fleet's robots load one model file: the SVR is fitted once; what it predicts is what a fit of its own
    gives, and a model with other samples (or hyperparameters) gets a fit of its own."""
    from runtime.allocation.dr import interference as I
    samples = [(n, d, 0.05 * n - 0.002 * d * n) for n in (1, 2, 3, 4) for d in (1.0, 3.0, 6.0)]
    a, b = I.InterferenceModel(samples, C=2.0, gamma=0.5), I.InterferenceModel(list(samples), C=2.0, gamma=0.5)
    assert a._svr is b._svr
    other = I.InterferenceModel(samples, C=3.0, gamma=0.5)
    assert other._svr is not a._svr
    fresh_svr, fresh_scale = a._fit_svr()
    assert fresh_svr is not a._svr
    lo, span, mean, sd = fresh_scale
    for n, d in ((1.5, 2.0), (3.0, 5.5), (4.0, 0.0)):
        x = (np.array([[n, d]]) - lo) / span
        assert a.predict(n, d) == pytest.approx(float(fresh_svr.predict(x)[0]) * sd + mean, rel=0, abs=1e-12)
    for k in range(I.MAX_FITS + 3):                      # the cache stays bounded
        I.InterferenceModel(samples, C=1.0 + k, gamma=0.5)
    assert len(I._FITS) <= I.MAX_FITS
