//! The bundled breast-like phantom, made by code.
