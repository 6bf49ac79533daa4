"""Simulation: MuJoCo execution of a RobotPlan with the object, success per stage (issue 8)."""
