"""Expert-data pipeline (thesis §3.4.1): goals -> minimum-time minimum-jerk references
-> geometric expert in the batched simulator -> versioned LeRobot v3.0 datasets."""
