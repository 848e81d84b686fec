"""Files in and out: scenario and scene loading, the shipped examples, MCAP logs and the Foxglove scene."""
