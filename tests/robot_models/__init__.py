"""Tests of robot_models/."""
