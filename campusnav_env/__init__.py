"""CampusNav: a Gymnasium environment for navigation and dynamic routing in changing road maps."""
