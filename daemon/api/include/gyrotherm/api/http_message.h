// HttpRequest and HttpResponse (http_server.h) as complete types, with what
// Boost.Beast offers to build and read them (verb, field, status, body): for
// the files that do, not for every user of http_server.h and api.h. It does
// not bring in Beast's parser, serializer or Asio.
#pragma once

#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>

#include "gyrotherm/api/http_server.h"
