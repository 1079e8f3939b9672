"""Simulated robot logs: a scenario (plan, objects, doors, people, robot path, sensors) rendered by
ray casting into MCAP, ROS 1 bags or ROS 2 bags, with a ground-truth file (``ltmap simulate``).

Modules: ``scenario`` (YAML schema and validation), ``scene`` (world primitives and the ray-casting
kernel), ``sensors`` (sensor frames and renders), ``logwriter`` (the three log formats),
``simulate`` (timeline, noise, messages, ground truth).
"""
