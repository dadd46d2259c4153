"""Climb orchestration: plan a climb, execute it against the simulator, record it."""
