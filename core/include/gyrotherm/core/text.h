// Text made safe for where it is written: HTML (reports, the lab summary)
// and C block comments (the coefficient headers).
#pragma once

#include <string>
#include <string_view>

namespace gyrotherm::text {

// HTML text or attribute value: & < > " ' as entities.
std::string html_escape(std::string_view s);

// Inside a C block comment: a control character (a newline would start a
// line that does not continue the comment) becomes a space, and a space is
// put between the two characters of "*/" (would end the comment), "/*"
// (-Wcomment) and "??" (a trigraph: "??/" before a newline splices lines
// under -std=c99).
std::string c_comment_text(std::string_view s);

}  // namespace gyrotherm::text
