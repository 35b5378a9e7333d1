"""``openemt demo``: the whole pipeline on the simulated tracker (no hardware): simulate,
calibrate, correct, solve and score, ending in an HTML report and the next commands to try.

The steps are :func:`openemt.report.run_demo`'s; each is announced before it runs.
"""

from ._common import workflow_command

register = workflow_command("demo", "report", "DemoOptions", "run_demo")
