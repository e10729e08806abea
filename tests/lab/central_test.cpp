// central tests: see below
