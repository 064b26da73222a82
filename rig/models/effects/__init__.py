"""The effects the paper's model leaves out: the built-in ones, the empirical shapes, effects written by
the user, and what the depth format itself does to every model (`file_physics`)."""
