"""``flightgp campaign``: many co-simulations, diagnoses, bench cases, reproductions and QTGs as
one campaign on Dask, on one machine or a cluster (docs/campaigns.md).

:mod:`~validation.campaign.spec` reads and expands the spec, :mod:`~validation.campaign.tasks`
holds what the workers run, :mod:`~validation.campaign.runner` drives Dask and
:mod:`~validation.campaign.results` writes the results.
"""
from validation.campaign.results import TaskResult, read_result, task_folder
from validation.campaign.runner import CampaignRun, run_campaign
from validation.campaign.spec import CampaignSpec, Task, parse_spec, read_spec

__all__ = ["CampaignRun", "CampaignSpec", "Task", "TaskResult", "parse_spec", "read_result", "read_spec",
           "run_campaign", "task_folder"]
