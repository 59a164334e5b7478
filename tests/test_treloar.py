"""Material fitting as a prediction (experiments/verification/treloar.py): the shipped Treloar
(1944, Trans. Faraday Soc. 40:59) data, and a law fitted to his uniaxial test predicting his
equibiaxial and pure shear tests."""

import numpy as np
import pytest

from experiments.verification import treloar


def test_the_shipped_data_are_treloars_tables():
    """24 uniaxial, 16 equibiaxial and 13 pure shear points (the tabulation named in the file's
    header), stretches from 1.02 to 7.6, 4.45 and 4.97; the largest stresses 6.3176, 2.4426 and
    1.805 MPa (Treloar's 64.4, 24.9 and 18.4 kg/cm^2); the source is named in the file."""
    tests = treloar.data()
    assert {m: len(tests[m][0]) for m in treloar.MODES} == {
        "uniaxial": 24,
        "biaxial": 16,
        "planar": 13,
    }
    np.testing.assert_allclose([tests[m][0][-1] for m in treloar.MODES], [7.6, 4.45, 4.97])
    np.testing.assert_allclose([tests[m][1][-1] for m in treloar.MODES], [6.3176, 2.4426, 1.805])
    header = treloar.DATA.read_text().split("mode,strain,stress")[0]
    assert "Treloar (1944)" in header and "Trans. Faraday Soc. 40:59" in header
    assert "shared" not in str(treloar.DATA.resolve())


def test_yeoh_fitted_to_uniaxial_tension_predicts_the_other_tests():
    """Yeoh fitted to the uniaxial data alone follows them within 10% RMS (found 4.5%, nma.fit's
    relative measure) and predicts equibiaxial and pure shear tension within 35% and 25% RMS
    (found 22.7% and 12.9%): the prediction error a user of a tensile test alone accepts, and more
    than the fit's own, as the literature finds for Treloar's data."""
    r = treloar.fit_and_predict("yeoh")
    errors = {m: r["modes"][m]["rms"] for m in treloar.MODES}
    assert errors["uniaxial"] < 0.10
    assert errors["biaxial"] < 0.35 and errors["planar"] < 0.25
    assert errors["biaxial"] > errors["uniaxial"] and errors["planar"] > errors["uniaxial"]
    assert np.all(np.diff(r["modes"]["biaxial"]["model"]) > 0)  # stiffening, as the data


@pytest.mark.slow  # every law's fit: about ten seconds
def test_every_law_fits_or_is_refused_and_its_predictions_are_reported():
    """Each law nma.fit offers either fits the uniaxial data within 12% RMS or is refused by
    nma.fit with its reason (Gent and Mooney-Rivlin: their best fits are not Drucker-stable over
    the data's stretches); the three-term Ogden fit follows the uniaxial data best (found 1.5%)
    and predicts equibiaxial tension worst (found 60%): a closer fit is not a better law."""
    r = treloar.run()
    assert r["failures"] == [], r["failures"]
    fitted = {n: law for n, law in r["laws"].items() if "refused" not in law}
    assert {"ogden", "yeoh", "arruda_boyce"} <= set(fitted)
    assert all("Drucker" in law["refused"] for law in r["laws"].values() if "refused" in law)
    rms = {n: {m: law["modes"][m]["rms"] for m in treloar.MODES} for n, law in fitted.items()}
    assert min(rms, key=lambda n: rms[n]["uniaxial"]) == "ogden"
    assert max(rms, key=lambda n: rms[n]["biaxial"]) == "ogden"
