//! The front end that `pinrender render`, `pinrender render --scene` and `pinview` share
//! (feature `cli`): the render flags they all flatten with their range parsers
//! ([`flags::RenderFlags`]), the one rule of which estimators an input answers and which is
//! the default ([`estimators`]), and the one way a file given on the command line becomes a
//! medium within the command's memory budget ([`open::open_medium`]), through pinbake's one
//! source dispatch; and the density scale a viewer opens a volume at when none is given
//! ([`first_look`]).
//!
//! The flags are parsed once and resolved once (a [`crate::scene_media::Look`], an
//! estimator, a [`pin_volume::files::MemoryBudget`]); the resolved values go down to the
//! renderers, the parsed flags do not come back up.

pub mod estimators;
pub mod first_look;
pub mod flags;
pub mod open;

pub use estimators::{Holds, available, default_estimator};
pub use flags::RenderFlags;
pub use open::{Input, PinsWanted, holds, open_medium};
