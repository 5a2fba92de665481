"""Worlds the vehicle flies in beyond free space: quadrotor mazes (walls, floor, ceiling),
their cell graphs and batched collision checks. Pure geometry: arrays in, arrays out."""

from aerohrl.worlds.maze import MAZES, VEHICLE_RADIUS, WORLDS, Maze, corners, load_maze, maze_from_dict, world_maze

__all__ = ["MAZES", "VEHICLE_RADIUS", "WORLDS", "Maze", "corners", "load_maze", "maze_from_dict", "world_maze"]
