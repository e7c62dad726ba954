"""The HTML of every command's report, from the orchestrator's results (dynid.reports.pipeline)."""
from __future__ import annotations

from dynid.analysis.statistics.verdict import judged_kind
from dynid.reports.agreement_figure import agreement_section
from dynid.reports.bayes_section import bayes_sections
from dynid.reports.bona_section import excitation_section
from dynid.reports.diagnosis_section import diagnosis_lead, diagnosis_sections
from dynid.reports.didim_section import didim_sections
from dynid.reports.friction_section import asymmetric_friction_section
from dynid.reports.html import Section, para, render_idim_report, render_sections, verdict_block
from dynid.reports.physical_section import effects_section, physical_section
from dynid.reports.projection_section import ml_section, projection_section

__all__ = ["identification_html", "sample_html", "diagnosis_html", "excitation_html", "full_report_sections",
           "idim_extra_sections", "render_idim_report"]


def _title(ident) -> str:
    name, method = ident.robot.name, ident.method
    if method == "didim":
        return f"{'PC-' if ident.result.physical is not None else ''}DIDIM identification of {name}"
    return {"projection": f"Projection Method identification of {name}",
            "ml": f"Maximum-likelihood identification of {name}"}[method]


def _sections(ident) -> list:
    res = ident.result
    if ident.method == "didim":
        return didim_sections(res) + ([physical_section(res.physical)] if res.physical is not None else [])
    if ident.method == "projection":
        return [projection_section(res)]
    return [ml_section(res)]


def idim_extra_sections(ident) -> list:
    """The report sections of the optional parts of an IDIM run."""
    extra = []
    if ident.tilt is not None:
        extra.append(Section("gravity-tilt", "Direction of gravity (base tilt)", para(
            "The robot file's gravity was rotated by the base tilt estimated on the identification "
            "data (Gauss-Newton on the two angles with the base parameters profiled out), and "
            "every result of this report uses the rotated gravity. " + ident.tilt.sentence())))
    if ident.asymmetric_friction is not None:
        extra.append(asymmetric_friction_section(ident.asymmetric_friction))
    if ident.physical is not None:
        extra.append(physical_section(ident.physical,
                                      effects_spec=None if ident.effects is None else ident.effects.spec))
    if ident.effects is not None:
        extra.append(effects_section(ident.effects))
    if ident.export is not None:
        extra.append(ident.export.section())
    if getattr(ident.result, "agreement", None) is not None:
        extra.append(agreement_section(ident.result.agreement, ident.result.agreement_line))
    return extra


def identification_html(ident) -> str:
    """The HTML report of a run."""
    if ident.method == "idim":
        return render_idim_report(ident.result, ident.robot, ident.experiments[0], ident.validation,
                                  extra_sections=idim_extra_sections(ident), verdict=ident.verdict)
    data = ", ".join(str(getattr(e, "source", "") or "?") for e in ident.experiments)
    robot = getattr(ident.robot, "name", "?")
    return render_sections(_sections(ident), title=_title(ident), subtitle=data,
                           highlights=[("verdict", ident.verdict.status), ("robot", robot), ("data", data)],
                           verdict=verdict_block(ident.verdict, kind=judged_kind(ident.result)))




def sample_html(post, result, robot, experiment, verdict) -> str:
    """`dynid sample --report`: the identification it samples and the posterior's sections."""
    return render_idim_report(result, robot, experiment, extra_sections=bayes_sections(post), verdict=verdict)


def diagnosis_html(run) -> str:
    """`dynid diagnose --report`: the identification, its validation and the diagnosis' sections."""
    lead = diagnosis_lead(run.diagnosis, run.robot)      # the diagnosis first (issue 27 item 5)
    return render_idim_report(run.result, run.robot, run.experiment, run.validation, title=lead["title"],
                              extra_sections=lead["sections"], lead_sections=lead["lead"],
                              lead_highlights=lead["highlights"], verdict=run.verdict)


def excitation_html(res, robot) -> str:
    """`dynid excite --report`."""
    return render_sections([excitation_section(res, robot)], title=f"Excitation design for {robot.name}")


def full_report_sections(more, robot) -> list:
    """The sections of DIDIM, the posterior and the diagnosis of a full report (the ones that ran)."""
    sections = []
    if more.didim is not None:
        sections += didim_sections(more.didim)
    if more.posterior is not None:
        sections += bayes_sections(more.posterior)
    if more.diagnosis is not None:
        sections += diagnosis_sections(more.diagnosis, robot)
    return sections
