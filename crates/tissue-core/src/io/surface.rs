//! Surface mesh files: reading, welding, writing.
