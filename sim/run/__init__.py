"""Running a scenario: the runner's stepping loop, the recorder of log samples, load-time guards, kernel compilation."""
