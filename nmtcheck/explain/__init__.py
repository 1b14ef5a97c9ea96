"""What runs after the rules: the causes and reactions of a finding, and which rules
could not be evaluated on an input and why."""
