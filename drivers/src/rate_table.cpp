#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers {

std::string_view to_string(TableMode mode) {
  switch (mode) {
    case TableMode::kOff:
      return "off";
    case TableMode::kRate:
      return "rate";
    case TableMode::kPosition:
      return "position";
    case TableMode::kUnknown:
      return "unknown";
  }
  return "unknown";
}

std::string_view to_string(TableInterlock state) {
  switch (state) {
    case TableInterlock::kOpen:
      return "open";
    case TableInterlock::kClosed:
      return "closed";
    case TableInterlock::kFault:
      return "fault";
  }
  return "fault";
}

std::string table_transport(const TableConnection& connection) {
  if (!connection.transport.empty()) return connection.transport;
  return connection.profile == "aero" ? "serial" : "tcp";
}

}  // namespace gyrotherm::drivers
