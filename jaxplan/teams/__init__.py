"""Performance-based earthmoving team organization (Endo et al.): excavators (coordinators) recruit
dump trucks (cooperators) through a blackboard so that every site meets its deadline.

::

    from jaxplan.teams import paper_scenario, paper_config, simulate_site, run_sites, random_sites
    result, trace = simulate_site(paper_config(), paper_scenario())

See docs/teams.md for the model (Eqs. 1-4) and the simulation's conventions.
"""
from jaxplan.teams.params import STRATEGIES, SiteParams, TeamsConfig
from jaxplan.teams.scenario import PAPER, paper_config, paper_scenario, random_sites
from jaxplan.teams.sim import SiteResult, Trace, run_sites, simulate_site

__all__ = ["PAPER", "STRATEGIES", "SiteParams", "SiteResult", "TeamsConfig", "Trace",
           "paper_config", "paper_scenario", "random_sites", "run_sites", "simulate_site"]
