"""Monte Carlo campaigns of full simulated calibrations on Dask (docs/campaigns.md).

* :mod:`~stableins.campaign.config`: the campaign file, seeds × procedures × noise models × hidden effects;
* :mod:`~stableins.campaign.task`: one task through the library, simulate → calibrate → diagnose, as table rows;
* :mod:`~stableins.campaign.execution`: the tasks on a local Dask cluster or an existing scheduler, resumable;
* :mod:`~stableins.campaign.summary`: the results table, the summary against the design's bound, the plots.
"""
