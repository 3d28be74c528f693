"""The CampusNav glue: what knows both DCQN and CampusNav (the experiments, the ``dcqn-campusnav`` command line)."""
