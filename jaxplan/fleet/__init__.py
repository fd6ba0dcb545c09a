"""A fleet of rovers on one shared fabric (issue 34): built-in sites."""
from jaxplan.fleet.sites import SITES, site

__all__ = ["SITES", "site"]
