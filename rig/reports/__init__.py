"""What people read: the sigma-vs-range plot, the diagnosis plots and HTML page, text tables."""
