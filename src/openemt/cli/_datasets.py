"""``openemt datasets``: list the data sets bundled with openemt, and verify their checksums."""

from ._common import workflow_command

register = workflow_command("datasets", "datasets", "DatasetsOptions", "check_datasets")
