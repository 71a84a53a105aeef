#pragma once
// The reference of a scenario's option keys (docs/REFERENCE.md), generated from the
// option tables themselves (core/option_fields.h): each key with its form, limits and unit,
// its default (per profile for the `estimation:` block) and its line of documentation.
// `tofu reference` prints it; ctest `reference_doc` checks the document against it.

#include <string>

namespace tofu::harness {

/// The whole page, in Markdown.
std::string ScenarioReferenceMarkdown();

}  // namespace tofu::harness
