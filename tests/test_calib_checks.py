"""Calibration files checked at read time: finite values, pol/invpol round trip, missing blocks."""

from __future__ import annotations

import numpy as np
import pytest

from ifmi.geometry.camera import fit_inverse_polynomial, paracatadioptric_model
from ifmi.cli import main
from ifmi.errors import InputError
from ifmi.io.calib import INVERSE_TOLERANCE_PX, format_calib, inverse_polynomial_error, parse_calib

# The published calibration of a real 748x480 catadioptric camera quoted in DESIGN.md.
PUBLISHED = """#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). These are used by cam2world

5 -2.063866e+02 0.000000e+00 2.165610e-03 -4.495456e-06 1.810639e-08

#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). These are used by world2cam

12 293.052431 151.538629 -11.130942 27.892086 7.952091 -1.062672 10.373416 1.171771 -6.054173 0.762221 3.136665 0.865190

#center: "row" and "column", starting from 0 (C convention)

241.019976 385.783141

#affine parameters "c", "d", "e"

0.998881 -0.042038 0.045079

#image size: "height" and "width"

480 748
"""


def _without_comments(text: str) -> str:
    return "\n".join(ln for ln in text.splitlines() if not ln.startswith("#"))


def test_published_file_round_trips_well_within_the_tolerance():
    error, _ = inverse_polynomial_error(parse_calib(PUBLISHED))
    # OCamCalib fits to 0.01 px; six printed digits leave 0.0024 px here.
    assert error < 0.005 < INVERSE_TOLERANCE_PX


@pytest.mark.slow
@pytest.mark.parametrize("size", [(64, 64), (256, 256), (480, 640), (321, 257)])
def test_project_calibrations_round_trip(size):
    model = paracatadioptric_model(size, horizon_radius_px=0.3 * min(size))
    assert inverse_polynomial_error(model)[0] < 1e-3
    assert parse_calib(format_calib(model)) == model


@pytest.mark.parametrize(("old", "new", "message"), [
    ("5 -2.063866e+02", "5 nan", r"direct polynomial: value 2 is nan \(every value must be finite\)"),
    ("1.171771", "inf", r"inverse polynomial: value 9 is inf"),
    ("241.019976", "-inf", r"center \(row col\): value 1 is -inf"),
    ("0.998881", "NaN", r"affine \(c d e\): value 1 is nan"),
])
def test_non_finite_values_are_rejected(old, new, message):
    with pytest.raises(InputError, match=message):
        parse_calib(PUBLISHED.replace(old, new, 1), source="c.txt")


def test_an_inverse_that_does_not_invert_is_rejected_with_the_measured_error():
    model = parse_calib(PUBLISHED)
    # The inverse of another camera (horizon 10 % further out).
    other = fit_inverse_polynomial(np.asarray(model.pol) * [1.1, 1, 1 / 1.1, 1 / 1.21, 1 / 1.331], 440.0)
    text = format_calib(model).replace(
        f"{len(model.invpol)} " + " ".join(f"{v:.17g}" for v in model.invpol),
        f"{len(other)} " + " ".join(f"{v:.17g}" for v in other))
    with pytest.raises(InputError) as info:
        parse_calib(text, source="calib_results.txt")
    message = str(info.value)
    assert "inverse polynomial does not invert the direct one: round-trip error" in message
    measured = float(message.split("round-trip error ")[1].split(" px")[0])
    assert measured > 1.0 and "at most 0.1 px accepted" in message and "\n" not in message


def test_a_slightly_perturbed_inverse_passes_and_a_worse_one_fails():
    model = parse_calib(PUBLISHED)
    ok = (model.invpol[0] + 0.05,) + model.invpol[1:]
    bad = (model.invpol[0] + 0.2,) + model.invpol[1:]
    from dataclasses import replace

    assert inverse_polynomial_error(replace(model, invpol=ok))[0] == pytest.approx(0.05, abs=0.005)
    with pytest.raises(InputError, match=r"round-trip error 0\.2\d* px"):
        parse_calib(format_calib(replace(model, invpol=bad)))


def test_a_direct_polynomial_that_images_no_band_is_rejected():
    # z = pol(r) > 0 at the centre: the elevation falls from +90 degrees, no inverse exists.
    text = PUBLISHED.replace("5 -2.063866e+02", "5 2.063866e+02")
    with pytest.raises(InputError, match="ray elevation does not grow with the radius"):
        parse_calib(text)


@pytest.mark.parametrize(("line", "missing"), [
    ("5 -2.063866e+02", "direct polynomial"),
    ("12 293.052431", "inverse polynomial"),
    ("241.019976 385.783141", r"center \(row col\)"),
    ("0.998881 -0.042038 0.045079", r"affine \(c d e\)"),
    ("480 748", r"image size \(height width\)"),
])
def test_the_missing_block_is_named(line, missing):
    lines = PUBLISHED.splitlines()
    index = next(i for i, ln in enumerate(lines) if ln.startswith(line))
    text = "\n".join(lines[:index] + lines[index + 1:])
    with pytest.raises(InputError, match=rf"expected 5 data blocks, got 4 \(missing: {missing}\)$"):
        parse_calib(text)


@pytest.mark.parametrize(("line", "missing"), [
    ("241.019976 385.783141", r"center \(row col\)"),
    ("0.998881 -0.042038 0.045079", r"affine \(c d e\)"),
    ("480 748", r"image size \(height width\)"),
    ("12 293.052431", "direct polynomial or inverse polynomial"),
])
def test_the_missing_block_is_named_without_comment_lines(line, missing):
    lines = _without_comments(PUBLISHED).splitlines()
    text = "\n".join(ln for ln in lines if not ln.startswith(line))
    with pytest.raises(InputError, match=rf"\(missing: {missing}\)$"):
        parse_calib(text)


def test_cli_reports_a_bad_calibration_in_one_line(tmp_path, capsys):
    (tmp_path / "images").mkdir()
    (tmp_path / "calib_results.txt").write_text(PUBLISHED.replace("1.171771", "nan"))
    assert main(["estimate", str(tmp_path), "--out", str(tmp_path / "e.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"ifmi estimate: error: {tmp_path / 'calib_results.txt'}: inverse polynomial: "
                   f"value 9 is nan (every value must be finite)")


def test_byte_order_mark_and_non_utf8_comments_are_read(tmp_path):
    from ifmi.io.calib import read_calib

    path = tmp_path / "calib_results.txt"
    text = PUBLISHED.replace("(C convention)", "(C convention, caméra)")
    path.write_bytes(b"\xef\xbb\xbf" + text.encode("latin-1"))
    assert read_calib(path) == parse_calib(PUBLISHED)


def test_a_single_unrecognisable_block_is_not_guessed_at():
    # One three-number line fits several blocks: listing every reading would name them all.
    with pytest.raises(InputError, match=r"expected 5 data blocks, got 1 \(missing: cannot tell which "
                                         r"from the values\)$"):
        parse_calib("garbage 1 2 3\n")
