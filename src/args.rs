//! Command-line values shared by the `aorender` commands.

use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use clap::builder::TypedValueParser as _;

/// `--hemisphere` values: the library's names.
pub fn hemisphere_parser() -> impl clap::builder::TypedValueParser<Value = Hemisphere> {
    clap::builder::PossibleValuesParser::new(Hemisphere::ALL.map(Hemisphere::name))
        .map(|name: String| Hemisphere::from_name(&name).expect("a listed name"))
}

/// `--sampler` values: the library's names.
pub fn sampler_parser() -> impl clap::builder::TypedValueParser<Value = Sampler> {
    clap::builder::PossibleValuesParser::new(Sampler::ALL.map(Sampler::name))
        .map(|name: String| Sampler::from_name(&name).expect("a listed name"))
}
