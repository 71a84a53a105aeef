#pragma once
// Private to report/: the page of a `tofu search --out` directory: the search's margins over
// its simulations (best so far, each flight's, the failures where they were found), the
// ranked table of failures, and the page of each confirmed failure's shrunk flight.

#include <filesystem>
#include <string>

namespace tofu::report::html {

/// Whether `dir` holds a search (search.json of format tofu-search-1).
bool IsSearchDirectory(const std::filesystem::path& dir);

/// Writes the search's page into <staging>/index.html and each confirmed failure's flight
/// page under <staging>/failures/<id>/ (a flight whose files are unreadable gets a red row
/// saying why, not an error). Throws core::InputError for an unreadable search.json.
void WriteSearchPages(const std::filesystem::path& search_dir, const std::filesystem::path& staging);

}  // namespace tofu::report::html
