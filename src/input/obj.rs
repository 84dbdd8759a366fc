//! OBJ input: see [`super`].
