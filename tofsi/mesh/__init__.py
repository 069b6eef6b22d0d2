"""The structured quadrilateral mesh, its grading and channel, its quality measures, element layers and the motion band."""
