"""The shipped scenarios: YAML files that `canfdi sim --scenario NAME` loads by name."""
