#include "client/sparkline.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>

namespace tally {
namespace {

// Number of UTF-8 code points.
size_t glyphs(const std::string& s) {
  size_t n = 0;
  for (unsigned char c : s) n += (c & 0xC0) != 0x80;
  return n;
}

TEST(Sparkline, NeedsTwoPoints) {
  Sparkline s;
  EXPECT_EQ(s.render(10), "");
  s.add(1, 0.5);
  EXPECT_EQ(s.render(10), "");
  s.add(2, 0.25);
  EXPECT_EQ(glyphs(s.render(10)), 10u);
}

TEST(Sparkline, FallingErrorFallsFromFullToEmptyBlock) {
  Sparkline s;
  for (int i = 1; i <= 100; ++i) s.add(i, 1.0 / std::sqrt(i));  // the usual t^-1/2
  const std::string r = s.render(8);
  EXPECT_EQ(glyphs(r), 8u);
  EXPECT_EQ(r.substr(0, 3), "█");                // the largest error at the left
  EXPECT_EQ(r.substr(r.size() - 3), "▁");        // the newest, smallest at the right
  const std::string a = s.render(8, true);
  const std::string levels = " .:-=+*#";
  for (size_t i = 1; i < a.size(); ++i) EXPECT_LE(levels.find(a[i]), levels.find(a[i - 1])) << a;
}

TEST(Sparkline, FlatSeriesSitsMidHeight) {
  Sparkline s;
  s.add(0, 2.0);
  s.add(1, 2.0);
  s.add(2, 2.0);
  EXPECT_EQ(s.render(4, true), "----");
}

TEST(Sparkline, SkipsNonFiniteNonPositiveAndOutOfOrder) {
  Sparkline s;
  s.add(0, 1.0);
  s.add(1, std::nan(""));
  s.add(2, 0.0);
  s.add(3, -1.0);
  s.add(4, INFINITY);
  EXPECT_EQ(s.size(), 1u);
  s.add(5, 0.1);
  s.add(4.5, 0.5);  // older than the newest
  EXPECT_EQ(s.size(), 2u);
  EXPECT_EQ(s.render(2, true), "# ");
}

TEST(Sparkline, MemoryStaysBoundedAndEndpointsSurvive) {
  Sparkline s(64);
  for (int i = 1; i <= 100000; ++i) s.add(i, 1.0 / i);
  EXPECT_LE(s.size(), 64u);
  const std::string r = s.render(5, true);
  EXPECT_EQ(r.front(), '#');
  EXPECT_EQ(r.back(), ' ');
}

TEST(Sparkline, Utf8Detection) {
  const char* saved = std::getenv("LC_ALL");
  std::string keep = saved ? saved : "";
  setenv("LC_ALL", "en_US.UTF-8", 1);
  EXPECT_TRUE(terminal_is_utf8());
  setenv("LC_ALL", "C", 1);
  EXPECT_FALSE(terminal_is_utf8());
  if (saved) setenv("LC_ALL", keep.c_str(), 1); else unsetenv("LC_ALL");
}

}  // namespace
}  // namespace tally
