#pragma once
// Private to report/: the pieces every report page is made of: escaped text, numbers and
// fields of a summary for table cells, the page's head and foot, sections, badges, and
// images inlined or copied beside the page. (HtmlEscape, Base64 and ScriptSafeJson, public,
// are declared in html_report.h and defined in html_page.cc.)

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

namespace tofu::report::html {

/// HtmlEscape.
std::string E(std::string_view text);

/// A relative path as an href: every byte outside the unreserved set percent-encoded.
std::string Href(const std::filesystem::path& relative);

/// 4 significant digits; "n/a" when not finite.
std::string Number(double v);
/// A field of a summary object for a table cell: numbers with 4 significant digits,
/// booleans as yes/no, missing or null as a dash (escaped HTML).
std::string Field(const nlohmann::json& object, const std::string& key);
/// A number field of `object`, or nullopt when it is missing or not a number.
std::optional<double> OptionalNumber(const nlohmann::json& object, const std::string& key);
/// A string field of `object`, or "" when it is missing or not a string (not escaped).
std::string StringField(const nlohmann::json& object, const std::string& key);
/// Rounded for the page's data: the plot needs no more digits than a screen shows.
double Rounded(double v, int significant);

/// Where a page is written and how it links to what surrounds it.
struct PageContext {
  std::filesystem::path page_dir;  ///< the (staging) directory the page is written into
  std::string back_href;           ///< link to the check overview, or ""
  std::string log_href;            ///< link to the run's log, or ""
};

/// From <!DOCTYPE> to <body>, with the style sheet.
std::string PageHead(const std::string& title);
/// The footer, the plot script when the page has plots, and the end of the document.
std::string PageFoot(bool with_plots);
/// A pass or fail badge.
std::string Badge(bool pass, std::string_view pass_text = "PASSED",
                  std::string_view fail_text = "FAILED");
/// An image as a data URI (self-contained page) or, when large, a file copied into media/.
std::string ImageSource(const std::filesystem::path& file, const PageContext& ctx);
/// A file (a video clip) copied into the page's media/: its href.
std::string CopyMedia(const std::filesystem::path& file, const PageContext& ctx);
/// <section id=...><h2>title</h2>body</section> (the table of contents links it).
std::string Section(const std::string& id, const std::string& title, const std::string& body);

}  // namespace tofu::report::html
