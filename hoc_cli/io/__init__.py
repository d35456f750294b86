"""File formats: task YAML, CSV and MCAP. The maths modules never import this package."""
