"""Performance-based earthmoving team organization (Endo et al.): excavators (coordinators) recruit
dump trucks (cooperators) through a blackboard so that every site meets its deadline.

::

    from jaxplan.teams import paper_scenario, paper_config, simulate_site, run_sites, random_sites
    result, trace = simulate_site(paper_config(), paper_scenario())

See docs/teams.md for the model (Eqs. 1-4) and the simulation's conventions.
"""
from jaxplan.teams.generators import PAPER, paper_config, paper_scenario, random_sites
from jaxplan.teams.params import STRATEGIES, SiteParams, TeamsConfig, validate_site
from jaxplan.teams.report import check_paper_options, run_paper
from jaxplan.teams.sim import SiteResult, Trace, run_sites, run_sites_jit, simulate_site

__all__ = ["PAPER", "STRATEGIES", "SiteParams", "SiteResult", "TeamsConfig", "Trace", "check_paper_options",
           "paper_config", "paper_scenario", "random_sites", "run_paper", "run_sites", "run_sites_jit",
           "simulate_site", "validate_site"]
