"""Notes on selected effects: a Stribeck term that is the friction's Coulomb onset, and
fitted signs that contradict what an effect's name means."""
from __future__ import annotations

import numpy as np

__all__ = ["onset_note", "physics_note", "effect_title", "ONSET_VS_FACTOR", "ONSET_PEAK_FRACTION"]

#: a Stribeck term with Fs < 0 whose v_s is at most this many dead-zone widths, or at most
#: this fraction of the joint's peak speed, is a Coulomb onset
ONSET_VS_FACTOR = 2.0
ONSET_PEAK_FRACTION = 0.05


def onset_note(cand, values, settings, qd_peak=None):
    """Note (or "") when a selected Stribeck term is the friction's smooth Coulomb onset.

    dynid's friction model has `Fc sign(qd)`; a real (or simulated) friction rises to
    its Coulomb level over a small speed range (the independent plant: `Fc tanh(qd /
    0.01)`). The velocity dead zone (default 1 % of the peak speed) exists to drop the
    rows where that matters; when the onset is wider than the dead zone the rows just
    outside it carry the mismatch and a Stribeck term with `Fs < 0` and a small `v_s`
    takes it (measured on the clean plant, TX40 joint 2, default dead zone 0.02 rad/s:
    Fs < 0, v_s 0.016 rad/s, CV gain 14 %). "Small" is within `ONSET_VS_FACTOR`
    dead-zone widths or `ONSET_PEAK_FRACTION` of the joint's peak speed: `Fs < 0`
    says the friction is *below* its Coulomb level at low speed, which over a
    twentieth of the speed range is the onset of Coulomb friction, not a law over the
    motion (a curved viscous law shows at a v_s comparable to the speeds the joint
    reaches). It is kept in the model (it does lower the errors) but is not reported as
    an effect of the robot: it says the dead zone is narrower than the friction's onset.
    """
    if cand.name != "stribeck" or not len(values) or values[0] >= 0:
        return ""
    vs = float(cand.nonlinear.get("vs", np.inf))
    thr = settings.get("qd_threshold")
    j = cand.joint - 1
    limit = 0.0
    if thr is not None:
        thr = np.atleast_1d(np.asarray(thr, dtype=float))
        thr = float(thr[j] if thr.size > j else thr[0])
        if thr > 0:
            limit = ONSET_VS_FACTOR * thr
    if qd_peak is not None:
        limit = max(limit, ONSET_PEAK_FRACTION * float(np.asarray(qd_peak, dtype=float)[j]))
    if not vs <= limit:
        return ""
    dz = f"; velocity dead zone {thr:.3g} rad/s" if isinstance(thr, float) else ""
    return (f"Coulomb onset, not a missing effect: Fs < 0 with v_s = {vs:.3g} rad/s (low speed: "
            f"at most {limit:.3g} rad/s{dz}): the friction rises to its Coulomb level more "
            f"smoothly than sign(qd), over a range wider than the dead zone (kept in the model; a "
            f"dead zone of ~{3 * vs:.2g} rad/s would drop those rows)")


def physics_note(cand, values):
    """Say so when the fitted sign contradicts what the effect's name means."""
    v = np.asarray(values, dtype=float)
    if cand.name == "stribeck" and v[0] < 0:
        return ("Fs < 0: at low speed the friction is below the Coulomb + viscous line and rises "
                "to it over about v_s (a wide, smooth Coulomb onset or a curved viscous law)")
    if cand.name == "time_delay":
        return (f"torque samples {abs(1e3 * v[0]):.3g} ms {'late' if v[0] > 0 else 'early'} against "
                "the positions (the model is re-fitted on W(t - d))")
    if cand.name == "load_friction" and v[0] < 0:
        return "Fl < 0: the friction falls as the transmitted torque grows (not a load-dependent friction)"
    if cand.name == "payload" and "dM" + str(cand.params[0][2:]) in cand.active_params and v[0] < 0:
        return "dM < 0: less mass than modelled on the last link"
    return ""




def effect_title(name, values):
    """The name an added effect is reported under: the fitted sign decides what it is.

    A `stribeck` term with Fs < 0 is a friction that *rises* to its Coulomb level at low
    speed, the opposite of a Stribeck dip: it is reported as a low-speed friction rise,
    so that no note contradicts the name.
    """
    v = np.asarray(values, dtype=float)
    if name == "stribeck" and v.size and v[0] < 0:
        return "low-speed friction rise (Stribeck form, Fs < 0)"
    if name == "stribeck":
        return "Stribeck friction (low-speed dip)"
    return name
