#include "gyrotherm/core/text.h"

#include <gtest/gtest.h>

namespace gyrotherm::text {
namespace {

TEST(Text, HtmlEscapeReplacesTheFiveSpecialCharactersOnly) {
  EXPECT_EQ(html_escape(R"(<a href="x">Tom & Jerry's</a>)"),
            "&lt;a href=&quot;x&quot;&gt;Tom &amp; Jerry&#39;s&lt;/a&gt;");
  EXPECT_EQ(html_escape("°/h −20 °C"), "°/h −20 °C");
  EXPECT_EQ(html_escape(""), "");
}

TEST(Text, CCommentTextCannotEndOrSpliceTheComment) {
  EXPECT_EQ(c_comment_text("a */ b"), "a * / b");
  EXPECT_EQ(c_comment_text("/*x"), "/ *x");
  EXPECT_EQ(c_comment_text("what?\?/"), "what? ?/");  // (a trigraph in C)
  EXPECT_EQ(c_comment_text("two\nlines\tand\x7f"), "two lines and ");
  EXPECT_EQ(c_comment_text("**/"), "** /");
  EXPECT_EQ(c_comment_text("17-0042"), "17-0042");
}

}  // namespace
}  // namespace gyrotherm::text
