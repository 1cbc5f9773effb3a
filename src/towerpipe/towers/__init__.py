"""Towers: clustering tower points into towers, the rules that keep them, overhead wires and lines, and stable tower ids."""
