"""Worked example: the real KUKA LWR4+ recordings (URDF robot, 200 Hz, joint-torque sensors).

    python examples/kuka_lwr4/run.py [--out DIR] [--quiet]

Writes DIR/kuka_lwr4.html (one self-contained report), DIR/kuka_lwr4.json and
DIR/kuka_lwr4_identified.urdf:

* IDIM (OLS, per-joint WLS, %sigma, essential parameters) on recordings 2 + 3,
  validated on recording 1 -- the report's main sections;
* the other way round: identified on recording 1, validated on recording 2.
  That is the split FloBaRoID reports a held-out figure for; recordings 1 and
  2 follow the same trajectory, so it is the easier test. Identified on 1 and
  validated on the different trajectory 3 is shown too;
* held-out errors of every split, with the metric: relative error
  ||tau - tau_hat|| / ||tau|| over all joints and all decimated samples of the
  recording not used for identification, and per-joint RMS of tau - tau_hat (N m);
* the residual diagnosis of the model identified on 1, validated on 2;
* a URDF with a physically consistent standard set for the 2 + 3 model.

Everything comes from the files beside this script and the installed dynid.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SPLITS = [((2, 3), 1), ((1,), 2), ((1,), 3)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out", help="output folder (default ./out)")
    ap.add_argument("--quiet", action="store_true", help="print only the headline figures")
    args = ap.parse_args(argv)

    import pandas as pd

    import dynid
    from dynid.outputs import write_all
    from dynid.provenance import dumps_json, json_safe, versions
    from dynid.reports import tables as T
    from dynid.reports.diagnosis_section import diagnosis_sections
    from dynid.reports.html import Section, bullets, join, para, render_idim_report
    from dynid.reports.urdf_export import export_urdf

    def say(msg):
        if not args.quiet:
            print(msg, flush=True)

    t0 = time.perf_counter()
    robot = dynid.load_robot("kuka_lwr4")
    rec = {i: dynid.load_experiment(HERE / f"recording_{i}.toml", robot) for i in (1, 2, 3)}
    for i, e in rec.items():
        say(f"recording {i}: {e.n_samples} samples at {e.fs:.1f} Hz, reference shift "
            f"{e.meta.get('reference_shift')} samples (estimated)")

    runs, rows = {}, []
    for train, held in SPLITS:
        res = dynid.identify([rec[i] for i in train], robot)
        val = dynid.validate(res, rec[held], robot)
        key = "+".join(map(str, train)) + f"->{held}"
        runs[key] = (res, val)
        row = {"split": f"identify on {' + '.join(map(str, train))}, validate on {held}",
               "rel_error_identification": res.model.rel_error, "rel_error_held_out": val.rel_error,
               "n_essential": len(res.model.names), "n_held_out_samples": len(val.t)}
        row.update({f"rms_j{j + 1}": float(v) for j, v in enumerate(val.rms)})
        rows.append(row)
        say(f"{key}: identification {100 * res.model.rel_error:.2f} %, held-out {100 * val.rel_error:.2f} %; RMS "
            + " ".join(f"{v:.3f}" for v in val.rms))
    held_df = pd.DataFrame(rows).set_index("split")
    main_res, main_val = runs["2+3->1"]
    say("")
    say(main_res.summary())

    say("\nresidual diagnosis (identified on 1, validated on 2) ...")
    diag = dynid.diagnose(rec[1], robot, validation=rec[2], idim_result=runs["1->2"][0])
    say(diag.summary())

    say("\nURDF export of the 2 + 3 model ...")
    urdf = export_urdf(main_res, robot)
    p = urdf.prediction

    labels = {"rel_error_identification": "relative error, identification data",
              "rel_error_held_out": "relative error, held-out recording",
              "n_essential": "essential parameters", "n_held_out_samples": "held-out samples"}
    labels.update({f"rms_j{j}": f"RMS j{j} [N m]" for j in range(1, 8)})
    tab = T.make_table(held_df, "tab-held-out", "Held-out errors of every split",
                       formats={"rel_error_identification": "num", "rel_error_held_out": "num"},
                       labels=labels)
    flob = runs["1->2"][1].rel_error
    held_section = Section("held-out", "Held-out errors, both splits", join(
        para("Metric: relative error \u2016\u03c4 \u2212 \u03c4\u0302\u2016/\u2016\u03c4\u2016 over all 7 "
             "joints and all decimated samples of the recording that was not used for "
             "identification (\u03c4 measured by the joint-torque sensors, \u03c4\u0302 predicted by "
             "the essential WLS model from the measured positions, both processed with the "
             "identification's filter and decimation), and per-joint RMS of \u03c4 \u2212 \u03c4\u0302."),
        para(f"FloBaRoID reports a held-out figure for training on recording 1 and validating on 2; "
             f"dynid's figure for that split is {100 * flob:.2f} %. Recordings 1 and 2 repeat the "
             f"same trajectory, so that split tests repeatability more than generalisation; "
             f"identified on 1 and validated on the different trajectory 3 the error is "
             f"{100 * runs['1->3'][1].rel_error:.1f} %: one trajectory does not excite enough to "
             f"generalise, two (2 + 3 -> 1: {100 * main_val.rel_error:.2f} %) do."),
        bullets([
            "The data were filtered at 2-3 Hz by the recording script (see PROVENANCE.md): the "
            "residual is smooth and correlated, so %\u03c3 computed as if it were white noise are "
            "optimistic; the held-out errors are the honest measure here.",
            "The motion is slow (|qd| < 1 rad/s): the gravity parameters (MY2R, MY4R: %\u03c3 "
            "< 0.2 %) are far better determined than the inertias, several of which come out "
            "with impossible values (ZZ1R < 0, Ia3 < 0): they compensate what the 2 Hz filtering "
            "and the sensor offsets leave, not rigid-body inertia. The URDF section shows what "
            "making them physical costs.",
        ])), tables=[tab])
    sections = [held_section] + diagnosis_sections(diag, robot) + [urdf.section()]
    html = render_idim_report(main_res, robot, rec[2], main_val, extra_sections=sections,
                              title="KUKA LWR4+, real data: identified on recordings 2 + 3, "
                                    "validated on 1 (and 1 -> 2)")
    doc = json_safe({
        "example": "kuka_lwr4",
        "metric": "relative error ||tau - tau_hat|| / ||tau|| over all joints and decimated samples "
                  "of the held-out recording; per-joint RMS of tau - tau_hat in N m",
        "held_out": held_df.reset_index().to_dict(orient="records"),
        "idim": main_res.to_dict(), "validation": main_val.to_dict(),
        "idim_1": runs["1->2"][0].to_dict(), "validation_1_on_2": runs["1->2"][1].to_dict(),
        "diagnosis": diag.to_dict(), "urdf_export": urdf.to_dict(), "versions": versions(),
    })
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_all([(out / "kuka_lwr4.html", html), (out / "kuka_lwr4.json", dumps_json(doc)),
                    (out / "kuka_lwr4_identified.urdf", urdf.text)])

    for (train, held), row in zip(SPLITS, rows):
        print(f"KUKA held-out {'+'.join(map(str, train))} -> {held}: relative error "
              f"{100 * row['rel_error_held_out']:.2f} %, RMS [N m] "
              + " ".join(f"{row[f'rms_j{j}']:.3f}" for j in range(1, 8)))
    chosen = ", ".join(f"{e.name} (joint {e.joint})" for e in diag.selected) or "nothing"
    print(f"KUKA diagnosis (1 -> 2) selected: {chosen}")
    print(f"KUKA URDF: {'consistent' if urdf.consistent else 'NOT consistent'}, "
          f"{'reproduces' if urdf.reproduces else 'does not reproduce'} the identified parameters; "
          f"relative error on 2 + 3: model {100 * p['rel_error_identified_model']:.2f} %, URDF set "
          f"{100 * p['rel_error_chosen_set']:.2f} %")
    print(f"wrote {out / 'kuka_lwr4.html'}, {out / 'kuka_lwr4.json'} and "
          f"{out / 'kuka_lwr4_identified.urdf'} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
