"""Orchestration: the experiment, replay and reprocessing, the one analysis pipeline, reports.

Modules here combine nodes, io and core into what a command does; they hold no numerics.
"""
