"""IDIM: the inverse dynamic identification model identified by least squares (section 2).

`identify_idim(experiment, robot)` runs the whole of section 2 of Gautier,
Janot, Vandanjon (2010): filtering and differentiation of q, the base
regressor, parallel decimation (eqs. (8)-(9)), OLS (eqs. (11)-(15)),
per-joint WLS (eq. (16)), and the essential parameters (Pham & Gautier 1991)
by iterative removal from the WLS solution.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters
from dynid.analysis.processing.observation import Observation, concatenate, observe
from dynid.analysis.results import ModelResults
from dynid.dynamics.base_parameters import base_parameters
from dynid.provenance import data_hash, json_safe, versions


@dataclass(eq=False)
class IDIMResult(ModelResults):
    """Everything an IDIM identification produced.

    Its parameters (`params`, `bse`, `conf_int()` ...) are those of `model`,
    the essential WLS estimate; `ols`, `wls` and `essential` keep the others.
    """

    method = "IDIM"

    robot_name: str
    base: object                 # BaseParameters
    ols: object                  # IdentificationResult on all base parameters
    wls: object                  # IdentificationResult (per-joint weighted)
    essential: object            # EssentialResult (from the WLS solution)
    observation: Observation
    settings: dict
    notices: list = field(default_factory=list)
    data_hash: str = ""
    source: str = ""
    truth: dict = None           # true base-parameter values, for simulated data
    robot: object = None         # the Robot identified (for validate() and predictions)

    @property
    def model(self):
        """The identified model users predict with: the essential WLS estimate."""
        return self.essential.result

    def parameter_table(self):
        """One row per base parameter: relation, OLS and WLS value and %σ, essential flag.

        Returns
        -------
        pandas.DataFrame
            One row per base parameter.
        """
        rows = []
        ess = dict(zip(self.model.names, zip(self.model.chi, self.model.rel_sigma)))
        for k, name in enumerate(self.base.names):
            rows.append({
                "name": name,
                "relation": self.base.relations[k],
                "ols": self.ols.chi[k], "ols_rel_std": self.ols.rel_sigma[k],
                "wls": self.wls.chi[k], "wls_rel_std": self.wls.rel_sigma[k],
                "essential": name in ess,
                "essential_value": ess[name][0] if name in ess else np.nan,
                "essential_rel_std": ess[name][1] if name in ess else np.nan,
            })
        return pd.DataFrame(rows).set_index("name")

    def summary(self):
        lines = [f"IDIM identification of robot '{self.robot_name}' from {self.source}",
                 f"  samples: {self.observation.n_raw} raw -> {self.observation.n_samples} decimated "
                 f"(fc = {self.settings['fc_position']:g} Hz, nd = {self.settings['nd']})",
                 f"  base parameters: {self.base.n_base}, essential: {len(self.model.names)}",
                 f"  relative error ||Y - W chi|| / ||Y||: OLS {self.ols.rel_error:.4f}, "
                 f"WLS {self.wls.rel_error:.4f}, essential {self.model.rel_error:.4f}",
                 ""]
        lines.append(self.essential.result.summary())
        if self.notices:
            lines += ["", "Notices:"] + [f"  - {n}" for n in self.notices]
        return "\n".join(lines)

    def to_dict(self):
        def params(res):
            return [{"name": n, "value": v, "std": s, "rel_std_percent": r}
                    for n, v, s, r in zip(res.names, res.chi, res.sigma, res.rel_sigma)]
        return json_safe({
            "method": "IDIM",
            "robot": self.robot_name,
            "source": self.source,
            "settings": self.settings,
            "base_parameters": self.base.table(),
            "ols": {"parameters": params(self.ols), "rel_error": self.ols.rel_error,
                    "rms_per_joint": list(self.ols.rms), "cond": self.ols.cond},
            "wls": {"parameters": params(self.wls), "rel_error": self.wls.rel_error,
                    "rms_per_joint": list(self.wls.rms), "joint_sigma": list(self.wls.joint_sigma),
                    "cond": self.wls.cond},
            "parameters": params(self.model),
            "essential": self.essential.to_dict(),
            "rel_error": self.model.rel_error,
            "rms_per_joint": list(self.model.rms),
            "versions": versions(),
            "data_hash": self.data_hash,
            "notices": self.notices,
            "true_values": self.truth,
        })



def identify_idim(experiment, robot, *, settings=None, bp=None, max_error_growth=0.02,
                  progress=None):
    """Identify the base and essential parameters of `robot` from `experiment` (IDIM-LS/WLS).

    `experiment` may be a list of recordings: their observation systems are
    stacked (processed with the settings derived from the first one).
    """
    bp = base_parameters(robot) if bp is None else bp
    experiments = list(experiment) if isinstance(experiment, (list, tuple)) else [experiment]
    # settings derived from the first recording apply to all, so every row of the
    # stacked system is processed alike
    first = observe(experiments[0], robot, bp, settings, progress=progress)
    obs = concatenate([first] + [observe(e, robot, bp, first.settings) for e in experiments[1:]])
    names = list(bp.names)
    info = {k: v for k, v in obs.settings.items()}
    r_ols = ls.ols(obs.W, obs.tau, names, row_mask=obs.row_mask, settings=info)
    r_wls = ls.wls(obs.W, obs.tau, names, row_mask=obs.row_mask, settings=info)
    ess = essential_parameters(obs.W, obs.tau, names, ls.wls, max_error_growth=max_error_growth,
                               row_mask=obs.row_mask, settings=info)
    h = (experiments[0].data_hash() if len(experiments) == 1 else
         data_hash(*[np.frombuffer(e.data_hash().encode(), dtype=np.uint8) for e in experiments]))
    for r in (r_ols, r_wls, ess.result, ess.base):
        r.data_hash = h
    notices = [n for e in experiments for n in getattr(e, "notices", [])] + obs.notices
    return IDIMResult(robot_name=robot.name, base=bp, ols=r_ols, wls=r_wls, essential=ess,
                      observation=obs, settings=obs.settings, notices=notices, data_hash=h,
                      source=" + ".join(str(e.source) for e in experiments), robot=robot)
