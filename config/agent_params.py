"""Parameters of the agents' estimator and control law (what a robot is configured with).

Owned by the agent core (``agents``); kept here so that scenarios can carry them without the
config package importing the algorithms.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class EstimatorSpec(_Strict):
    """Tuning of the kinematic-phase estimators (placeholder fields; the agent core defines them)."""

    sigma_v: float | None = Field(
        None, ge=0, description="velocity-sensor noise the agents assume (m/s); default: the scenario's noise"
    )


class ControlSpec(_Strict):
    """The kinematic-phase control schedule (placeholder fields; the agent core defines them)."""

    force: float = Field(2.0, ge=0, description="Prop. 6 common force magnitude per agent (N)")
