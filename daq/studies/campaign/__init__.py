"""Campaigns: ``gvt analyze``, ``gvt frf`` and ``gvt modal`` over many logs as one Dask job (issue 31, docs/campaign.md).

``plan.py`` turns the logs and the verb's options into tasks (pure: no log is opened, nothing runs), ``tasks.py`` is
what a worker runs for one log (the same study functions the single-log verb runs, errors kept as one line and an exit
code), ``runner.py`` hands the tasks to a Dask cluster and collects the rows as they finish, ``table.py`` prints the
summary and says the campaign's exit code.
"""
