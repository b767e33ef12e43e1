// common/hash: the one SHA-256 / SHA-1 and the one FNV-1a, against published vectors.
#include <gtest/gtest.h>

#include <string>

#include "common/hash/digest.hpp"
#include "common/hash/fnv1a.hpp"

namespace tally {
namespace {

// FIPS 180-2 appendix examples ("abc", the 448-bit message) and the empty string.
TEST(Digest, Sha256MatchesFipsVectors) {
  EXPECT_EQ(sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(sha256_hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
}

TEST(Digest, Sha1MatchesFipsVector) {
  EXPECT_EQ(sha1_hex("abc"), "a9993e364706816aba3e25717850c26c9cd0d89d");
  EXPECT_EQ(sha1_hex(""), "da39a3ee5e6b4b0d3255bfef95601890afd80709");
}

// The streaming digest of a body cut at every place equals the one-shot digest.
TEST(Digest, Sha256InPartsEqualsOneShot) {
  std::string body;
  for (int i = 0; i < 300; ++i) body.push_back(static_cast<char>(i * 7 + 3));
  const std::string whole = sha256_hex(body);
  for (size_t cut = 0; cut <= body.size(); cut += 37) {
    Sha256 sha;
    sha.update(std::string_view(body).substr(0, cut));
    sha.update(std::string_view(body).substr(cut));
    EXPECT_EQ(sha.finish_hex(), whole) << "cut at " << cut;
  }
  Sha256 nothing;
  EXPECT_EQ(nothing.finish_hex(), sha256_hex(""));
}

TEST(Digest, HexEncodeIsLowerCaseTwoDigitsPerByte) {
  const unsigned char bytes[] = {0x00, 0x0f, 0xa0, 0xff};
  EXPECT_EQ(hex_encode(bytes, 4), "000fa0ff");
  EXPECT_EQ(hex_encode(bytes, 0), "");
}

// Vectors of the FNV reference (www.isthe.com/chongo/src/fnv/test_fnv.c, FNV-1a 64).
TEST(Fnv1a, MatchesReferenceVectors) {
  static_assert(fnv1a64("") == 0xcbf29ce484222325ULL);
  EXPECT_EQ(fnv1a64("a"), 0xaf63dc4c8601ec8cULL);
  EXPECT_EQ(fnv1a64("foobar"), 0x85944171f73967e8ULL);
  EXPECT_EQ(fnv1a64(std::string_view("\xff", 1)), (0xcbf29ce484222325ULL ^ 0xffULL) * 0x100000001b3ULL);
}

}  // namespace
}  // namespace tally
