//! STL input (binary and ascii): see [`super`].
