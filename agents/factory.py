"""Builds an agent from a scenario, the same way for every engine.

The in-process engine (:func:`build_team`, every agent in one team) and the daemons both call
:func:`build_agent` on the agent's view of the scenario (``Scenario.agent_view``; and
``net.link.build_in_links`` for the links), so a lockstep run over Zenoh and an in-process run with the
same seed start identical. A control law of the user's (``control.law``, agents/laws.py) is imported here.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path

from agents.agent import AgentCore
from agents.laws import ControlLawError, LawFactory, LawSetup
from agents.team import Member, TeamCore
from config.agent_params import LAW_REF
from config.scenario import AgentView


def member(view: AgentView) -> Member:
    """The agent of ``view`` as a team's member (its control law built)."""
    return Member(
        agent_id=view.agent,
        neighbours=list(view.neighbours),
        n=view.n,
        dt=view.dt,
        sigma_v=view.sigma_v,
        estimator=view.estimator,
        control=view.control,
        dynamics=view.dynamics,
        law=build_law(view),
    )


def build_agent(view: AgentView) -> AgentCore:
    return AgentCore(*member(view))


def build_team(views: Sequence[AgentView], ring: int = 2) -> TeamCore:
    """The agents of ``views`` as one team (rows in that order), each as :func:`build_agent` builds it;
    ``ring``: the slots of its OUT ring (agents.team.TeamCore)."""
    return TeamCore([member(v) for v in views], ring)


def build_law(view: AgentView):
    """The agent's instance of the scenario's control law, or None; ControlLawError (one line
    naming the law) if it cannot be imported or built."""
    ref = view.control.law
    if not ref:
        return None
    factory = load_law_factory(ref)
    setup = LawSetup(agent=view.agent, n=view.n, dt=view.dt, neighbours=tuple(view.neighbours))
    try:
        law = factory(setup, **view.control.law_params)
    except ControlLawError as exc:
        raise ControlLawError(f"control.law {ref!r}: {exc}") from None
    except Exception as exc:  # the user's code: a wrong parameter name, a bad value
        raise ControlLawError(f"control.law {ref!r}: building agent {view.agent}'s law failed with "
                              f"{type(exc).__name__}: {exc} (control.law_params: "
                              f"{dict(view.control.law_params)})") from None
    if not callable(law):
        raise ControlLawError(f"control.law {ref!r}: the factory returned {type(law).__name__}, "
                              f"not a callable law(x) -> (fx, fy, tau)")
    return law


def load_law_factory(ref: str) -> LawFactory:
    """The factory named by ``package.module:attr`` or ``path/to/file.py:attr``."""
    m = LAW_REF.fullmatch(ref)
    if m is None:
        raise ControlLawError(f"control.law {ref!r}: expected 'package.module:factory' or 'path/to/file.py:factory'")
    target, attr = m.group("target"), m.group("attr")
    try:
        if target.endswith(".py"):
            path = Path(target)
            if not path.is_file():
                raise ControlLawError(f"control.law {ref!r}: no such file {target}")
            # one module per file, under a name of its own (two laws in files of the same name do not clash)
            name = "coload_law_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
            module = sys.modules.get(name)
            if module is None:
                folder = str(path.resolve().parent)
                if folder not in sys.path:  # as for a script: the law's sibling modules import
                    sys.path.insert(0, folder)
                spec = importlib.util.spec_from_file_location(name, path)
                if spec is None or spec.loader is None:
                    raise ControlLawError(f"control.law {ref!r}: {target} is not a Python file")
                module = importlib.util.module_from_spec(spec)
                sys.modules[name] = module
                try:
                    spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[name]
                    raise
        else:
            module = importlib.import_module(target)
    except ControlLawError:
        raise
    except Exception as exc:  # ImportError, or anything the module raises while it is imported
        raise ControlLawError(f"control.law {ref!r}: cannot import {target}: {type(exc).__name__}: {exc}") from None
    obj = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise ControlLawError(f"control.law {ref!r}: {target} has no {attr}") from None
    if not callable(obj):
        raise ControlLawError(f"control.law {ref!r}: {attr} is a {type(obj).__name__}, not a factory")
    return obj
