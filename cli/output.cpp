#include "output.h"

#include <algorithm>
#include <iostream>

namespace gyrotherm::cli {

int fail(const std::string& message, int code, std::string_view who) {
  std::cerr << who << ": " << message;
  if (message.empty() || message.back() != '\n') std::cerr << '\n';
  return code;
}

std::size_t cells(std::string_view s) {
  std::size_t n = 0;
  for (const char c : s) n += (static_cast<unsigned char>(c) & 0xC0) != 0x80;
  return n;
}

std::string table(const std::vector<std::string>& header, const std::vector<Align>& align,
                  const std::vector<std::vector<std::string>>& rows, std::string_view indent) {
  std::vector<std::size_t> width(header.size());
  auto measure = [&](const std::vector<std::string>& row) {
    for (std::size_t c = 0; c < row.size() && c < width.size(); ++c) {
      width[c] = std::max(width[c], cells(row[c]));
    }
  };
  measure(header);
  for (const auto& r : rows) measure(r);
  std::string out;
  auto emit = [&](const std::vector<std::string>& row) {
    std::string line(indent);
    for (std::size_t c = 0; c < row.size() && c < width.size(); ++c) {
      if (c > 0) line += "  ";
      const std::string pad(width[c] - cells(row[c]), ' ');
      line += align[c] == Align::kRight ? pad + row[c] : row[c] + pad;
    }
    while (!line.empty() && line.back() == ' ') line.pop_back();
    out += line + "\n";
  };
  emit(header);
  for (const auto& r : rows) emit(r);
  return out;
}

std::string table(const std::vector<std::string>& header,
                  const std::vector<std::vector<std::string>>& rows, std::size_t left,
                  std::string_view indent) {
  std::vector<Align> align(header.size(), Align::kRight);
  std::fill_n(align.begin(), std::min(left, align.size()), Align::kLeft);
  return table(header, align, rows, indent);
}

}  // namespace gyrotherm::cli
