#include "report/html_page.h"

#include <cctype>
#include <cmath>
#include <cstdint>

#include <fmt/format.h>

#include "core/file_io.h"
#include "report/html_report.h"
#include "report/html_report_assets.h"

namespace tofu::report {

namespace fs = std::filesystem;
using nlohmann::json;

std::string HtmlEscape(std::string_view text) {
  std::string out;
  out.reserve(text.size() + text.size() / 8);
  for (const char ch : text) {
    switch (ch) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      case '\t':
      case '\n':
      case '\r':
        out += ch;
        break;
      default:
        // Other C0 controls are not allowed in HTML text; they carry nothing to show.
        if (static_cast<unsigned char>(ch) >= 0x20 && ch != 0x7f) out += ch;
    }
  }
  return out;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (static_cast<uint8_t>(bytes[i]) << 16) |
                       (static_cast<uint8_t>(bytes[i + 1]) << 8) |
                       static_cast<uint8_t>(bytes[i + 2]);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = static_cast<uint8_t>(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v =
        (static_cast<uint8_t>(bytes[i]) << 16) | (static_cast<uint8_t>(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

std::string ScriptSafeJson(const json& value) {
  const std::string text = value.dump(-1, ' ', false, json::error_handler_t::replace);
  std::string out;
  out.reserve(text.size());
  // '<', '>' and '&' can only occur inside JSON strings, where \u escapes mean the same.
  for (const char ch : text) {
    switch (ch) {
      case '<':
        out += "\\u003c";
        break;
      case '>':
        out += "\\u003e";
        break;
      case '&':
        out += "\\u0026";
        break;
      default:
        out += ch;
    }
  }
  return out;
}

namespace html {

std::string E(std::string_view text) { return HtmlEscape(text); }

// A relative path as an href: every byte outside the unreserved set percent-encoded.
std::string Href(const fs::path& relative) {
  std::string out;
  for (const char ch : relative.generic_string()) {
    const unsigned char c = static_cast<unsigned char>(ch);
    if (std::isalnum(c) != 0 || ch == '-' || ch == '_' || ch == '.' || ch == '~' || ch == '/') {
      out += ch;
    } else {
      out += fmt::format("%{:02X}", c);
    }
  }
  return out;
}

std::string Number(double v) {
  if (!std::isfinite(v)) return "n/a";
  return fmt::format("{:.4g}", v);
}

// A field of a summary object for a table cell: numbers with 4 significant digits,
// booleans as yes/no, missing or null as a dash.
std::string Field(const json& object, const std::string& key) {
  if (!object.is_object()) return "–";
  const auto it = object.find(key);
  if (it == object.end() || it->is_null()) return "–";
  if (it->is_boolean()) return it->get<bool>() ? "yes" : "no";
  if (it->is_number()) return Number(it->get<double>());
  if (it->is_string()) return E(it->get<std::string>());
  return E(it->dump());
}

std::optional<double> OptionalNumber(const json& object, const std::string& key) {
  if (!object.is_object()) return std::nullopt;
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) return std::nullopt;
  return it->get<double>();
}

std::string StringField(const json& object, const std::string& key) {
  if (!object.is_object()) return {};
  const auto it = object.find(key);
  return it != object.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// Rounded for the page's data: the plot needs no more digits than a screen shows.
double Rounded(double v, int significant) {
  if (!std::isfinite(v) || v == 0.0) return v;
  const double scale = std::pow(10.0, significant - 1 - std::floor(std::log10(std::abs(v))));
  return std::round(v * scale) / scale;
}

std::string PageHead(const std::string& title) {
  return fmt::format(
      "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
      "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
      "<title>{}</title>\n<style>\n{}</style>\n</head>\n<body>\n",
      E(title), kReportCss);
}

std::string PageFoot(bool with_plots) {
  std::string out =
      "<footer>Written by <code>tofu report</code>. Self-contained: no network is used "
      "to view this page.</footer>\n";
  if (with_plots) out += fmt::format("<script>\n{}</script>\n", kPlotScript);
  return out + "</body>\n</html>\n";
}

std::string Badge(bool pass, std::string_view pass_text,
                  std::string_view fail_text) {
  return fmt::format("<span class=\"badge {}\">{}</span>", pass ? "pass" : "fail",
                     pass ? pass_text : fail_text);
}

// An image as a data URI (self-contained page) or, when large, a file copied into media/.
std::string ImageSource(const fs::path& file, const PageContext& ctx) {
  constexpr std::uintmax_t kInlineMaxBytes = 6u << 20;
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (!ec && size <= kInlineMaxBytes) {
    const std::string ext = file.extension().string();
    const char* mime = ext == ".gif" ? "image/gif" : ext == ".jpg" ? "image/jpeg" : "image/png";
    return fmt::format("data:{};base64,{}", mime, Base64(core::ReadWholeFile(file, "image")));
  }
  fs::create_directories(ctx.page_dir / "media");
  fs::copy_file(file, ctx.page_dir / "media" / file.filename(),
                fs::copy_options::overwrite_existing);
  return Href(fs::path("media") / file.filename());
}

std::string CopyMedia(const fs::path& file, const PageContext& ctx) {
  fs::create_directories(ctx.page_dir / "media");
  fs::copy_file(file, ctx.page_dir / "media" / file.filename(),
                fs::copy_options::overwrite_existing);
  return Href(fs::path("media") / file.filename());
}

std::string Section(const std::string& id, const std::string& title, const std::string& body) {
  return fmt::format("<section id=\"{}\">\n<h2>{}</h2>\n{}</section>\n", id, E(title), body);
}

}  // namespace html
}  // namespace tofu::report
