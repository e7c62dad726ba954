"""Report section of `dynid.analysis.diagnosis.asymmetric_friction.AsymmetricFrictionResult`."""
from __future__ import annotations

from dynid.reports import tables as T
from dynid.reports.html import Section, para


def asymmetric_friction_section(result, *, id="asymmetric-friction"):
    """Table 2 layout of Bona & Curatella (2005): beta_v+-, beta_c+- per joint, with sigma."""
    df = result.table2_frame()
    tab = T.make_table(df, f"{id}-table",
                       "Asymmetric friction per joint (eq. (2) of Bona & Curatella 2005), from the "
                       "essential model + |qd| columns; \u03c3 from the covariance of that fit; \u03b2v in "
                       "N m s/rad, \u03b2c in N m" + (" (N s/m and N on the prismatic joints "
                                                     + ", ".join(map(str, result.prismatic)) + ")"
                                                     if result.prismatic else ""),
                       labels={c: c.replace("sigma ", "\u03c3 ") for c in df.columns})
    body = para(f"\u03b2v\u00b1 = Fv \u00b1 dFv and \u03b2c\u00b1 = Fc \u00b1 Off (or \u00b1 dFc "
                f"when the model has no offset): the offset of a joint is the asymmetry of its "
                f"Coulomb friction. Relative error {100 * result.rel_error_before:.3f} % with "
                f"symmetric friction, {100 * result.fit.rel_error:.3f} % with asymmetric friction.",
                *[f" Note: {m}" for m in result.notices])
    return Section(id, "Asymmetric friction (Bona & Curatella 2005, Table 2 layout)", body,
                   tables=[tab], tables_first=True)
