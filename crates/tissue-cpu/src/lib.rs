//! The CPU reference path of tissue.
