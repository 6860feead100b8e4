defmodule ThinkingCap.Config.RosMap do
  @moduledoc """
  Imports a ROS `map_server` occupancy map: a YAML file (`image`,
  `resolution`, `origin`, `negate`, `occupied_thresh`, `free_thresh`,
  `mode`) and the binary PGM (P5) image it names.

  The rules are nav2 `map_io`'s for `mode: trinary` (the default): a pixel
  value v gives p = (255 − v)/255 (v/255 when `negate` is 1); the cell is
  occupied (100) when p > `occupied_thresh`, free (0) when p <
  `free_thresh`, unknown (−1) otherwise. Image row 0 is the top of the
  picture and grid row 0 the bottom (y grows upwards), so rows are flipped.
  `origin` is the pose of the lower-left cell. Other modes (`scale`, `raw`)
  and other image formats are refused with an error saying so.

  ## Bounds

  Both files are read within bounds, so that any bytes get an answer in
  time and memory bounded by the limits below, and every problem is a
  `ThinkingCap.Config.Error` naming the file and the place (at most 50,
  then how many more):

    * the YAML file: at most 64 KB of UTF-8, read by a strict reader of the
      part of YAML map files use (one mapping of the known keys, each
      once; scalars plain or quoted; `origin` as `[x, y]`, `[x, y, yaw]` or
      a block sequence; comments); anything else (unknown keys, nested
      mappings, anchors, tags, several documents) is an error at its line
      and column. Keys and values stay strings: no atom comes from a file.
      Values: `resolution` from 0.0001 to 100 m/cell, `origin` 2 or 3
      finite numbers within ±10⁶ m, thresholds in [0, 1] with
      `free_thresh` ≤ `occupied_thresh`, `negate` 0 or 1 (or false/true).
    * the image: `image` is resolved relative to the YAML's directory (an
      absolute path stays as it is, as in map_server; it is only ever read
      as a PGM) and must be a regular file. Its header (`P5`, width,
      height, maximum value 255, `#` comments) must fit in its first 4096
      bytes; width × height at most 10⁸ cells; the file must hold exactly
      the header and width × height bytes. Each is checked before the
      pixels are read, and refused at its byte offset.
  """

  alias ThinkingCap.Config.Error

  @max_yaml_bytes 64 * 1024
  @keys ~w(image resolution origin negate occupied_thresh free_thresh mode)
  @min_resolution 1.0e-4
  @max_resolution 100.0
  @max_coordinate 1.0e6
  @max_header 4096
  @max_cells 100_000_000
  @whitespace ~c" \t\r\n\v\f"

  @enforce_keys [:file, :width, :height, :resolution, :origin, :data]
  defstruct [:file, :width, :height, :resolution, :origin, :data]

  @typedoc """
  `data` holds one signed byte per cell (−1, 0..100), row-major from the
  bottom row: cell (col, row) is byte `row * width + col`.
  """
  @type t :: %__MODULE__{
          file: Path.t(),
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float(), float()},
          data: binary()
        }

  @doc """
  Loads the map described by the YAML file at `path`, within bounds (see
  the module documentation): every problem is an `Error` naming the file
  and the place (line and column in the YAML, byte offset in the PGM), at
  most 50 of them and then how many more.
  """
  @spec load(Path.t()) :: {:ok, t()} | {:error, [Error.t()]}
  def load(path) do
    with {:ok, text} <- read_yaml(path),
         {:ok, params} <- parse_yaml(text, path),
         image = Path.expand(params.image, Path.dirname(path)),
         {:ok, width, height, pixels} <- read_pgm(image) do
      {:ok,
       %__MODULE__{
         file: path,
         width: width,
         height: height,
         resolution: params.resolution,
         origin: params.origin,
         data: to_cells(pixels, width, height, params)
       }}
    else
      {:error, errors} -> {:error, Error.cap(errors)}
    end
  end

  @doc "The occupancy of cell (`col`, `row`): −1 unknown, 0 free .. 100 occupied."
  @spec cell(t(), non_neg_integer(), non_neg_integer()) :: -1..100
  def cell(%__MODULE__{width: w, height: h, data: data}, col, row)
      when col in 0..(w - 1) and row in 0..(h - 1) do
    <<_::binary-size(row * w + col), v::signed-8, _::binary>> = data
    v
  end

  @doc """
  Saves a map as `map_saver` does: the YAML file at `yaml_path` and, beside
  it, a binary PGM of the same base name. `map` is a `t()` or any map with
  `width`, `height`, `resolution`, `origin` (`{x, y}` or `{x, y, yaw}`) and
  `data` (one byte per cell in this module's layout; 1..99 count as
  occupied from 65 and free up to 19, as map_saver's default thresholds).
  Cells are written trinary: occupied black (0), free white (254), unknown
  grey (205); so `load/1` gives back the trinary map exactly.
  """
  @spec save(map(), Path.t()) :: :ok | {:error, String.t()}
  def save(%{width: w, height: h, resolution: res, origin: origin, data: data}, yaml_path)
      when is_integer(w) and w > 0 and is_integer(h) and h > 0 and byte_size(data) == w * h do
    {x, y, yaw} =
      case origin do
        {x, y} -> {x, y, 0.0}
        {x, y, yaw} -> {x, y, yaw}
      end

    pgm = Path.rootname(yaml_path) <> ".pgm"

    rows =
      for row <- (h - 1)..0//-1 do
        for <<v::signed-8 <- binary_part(data, row * w, w)>>, into: <<>>, do: <<pixel(v)>>
      end

    yaml = """
    image: #{Path.basename(pgm)}
    mode: trinary
    resolution: #{float(res)}
    origin: [#{float(x)}, #{float(y)}, #{float(yaw)}]
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    """

    with :ok <- write(pgm, ["P5\n# ThinkingCap map\n#{w} #{h}\n255\n" | rows]),
         :ok <- write(yaml_path, yaml) do
      :ok
    end
  end

  def save(_map, yaml_path),
    do: {:error, "#{yaml_path}: not saved: the map's data does not hold width × height cells"}

  # map_saver's trinary colours and default thresholds
  defp pixel(v) when v < 0, do: 205
  defp pixel(v) when v >= 65, do: 0
  defp pixel(v) when v <= 19, do: 254
  defp pixel(_v), do: 205

  defp float(v), do: :erlang.float_to_binary(v * 1.0, [:short])

  defp write(path, iodata) do
    case File.write(path, iodata) do
      :ok -> :ok
      {:error, reason} -> {:error, "cannot write #{path}: #{:file.format_error(reason)}"}
    end
  end

  @doc "The grid as a list of rows, bottom row first (for tests and tools)."
  @spec rows(t()) :: [[integer()]]
  def rows(%__MODULE__{width: w, data: data}) do
    for <<row::binary-size(w) <- data>>, do: for(<<v::signed-8 <- row>>, do: v)
  end

  ## YAML: a strict subset, enough for every map_server file
  #
  # Top-level `key: value` lines (known keys only, each once); a value is
  # a scalar (plain, 'single' or "double" quoted), a one-line flow
  # sequence of scalars (`[x, y, yaw]`) or a block sequence of scalars on
  # the lines below (`- x`); comments, blank lines and a leading `---`.
  # Anything else YAML has (nested mappings, anchors, tags, several
  # documents) is refused at its line. Keys and values stay strings: no
  # atom is made from the file. Read with our own scanner, not libyaml
  # (fast_yaml): it kills the VM on 30,000-deep nesting and gives no line
  # for a value that parses but is wrong.

  defp read_yaml(path) do
    with {:ok, size} <- regular(path, "the map's YAML file"),
         :ok <- at_most(path, size, @max_yaml_bytes, "a map's YAML file is limited to"),
         {:ok, text} <- read_whole(path),
         :ok <- ThinkingCap.Config.Source.utf8(path, text) do
      {:ok, text}
    end
  end

  defp regular(path, what) do
    case File.stat(path) do
      {:ok, %File.Stat{type: :regular, size: size}} ->
        {:ok, size}

      {:ok, %File.Stat{type: type}} ->
        fail(path, "#{what} is not a regular file (#{type})")

      {:error, reason} ->
        fail(path, "cannot read #{what}: #{:file.format_error(reason)}")
    end
  end

  defp at_most(_path, size, max, _what) when size <= max, do: :ok
  defp at_most(path, size, max, what), do: fail(path, "#{size} bytes: #{what} #{max} bytes")

  defp read_whole(path) do
    case File.read(path) do
      {:ok, text} -> {:ok, text}
      {:error, reason} -> fail(path, "cannot read the file: #{:file.format_error(reason)}")
    end
  end

  defp fail(path, message), do: {:error, [Error.new(path, {0, 0}, message)]}

  defp parse_yaml(text, path) do
    st = %{path: path, entries: %{}, errors: [], pending: nil, phase: :start}

    st =
      text
      |> String.split("\n")
      |> Enum.with_index(1)
      |> Enum.reduce(st, fn {line, n}, st ->
        yaml_line(st, String.trim_trailing(line, "\r"), n)
      end)
      |> close_pending()

    st = yaml_params(st)

    case st do
      %{errors: [], params: params} ->
        {:ok, params}

      %{errors: errors} ->
        {:error, errors |> Enum.reverse() |> Enum.sort_by(&{&1.line, &1.column})}
    end
  end

  defp yaml_error(st, pos, message),
    do: %{st | errors: [Error.new(st.path, pos, message) | st.errors]}

  defp yaml_line(st, line, n) do
    {indent, body} = indentation(line)

    cond do
      blank?(body) or st.phase == :skip ->
        st

      st.phase == :ended ->
        yaml_error(st, {n, indent + 1}, "text after the end of the document (...)")

      String.starts_with?(line, "\t") or String.starts_with?(body, "\t") ->
        yaml_error(st, {n, 1}, "a tab in the indentation: YAML indents with spaces")

      line == "---" or String.starts_with?(line, "--- ") ->
        if st.phase == :start and blank?(String.slice(line, 3..-1//1)),
          do: %{st | phase: :body},
          else: %{
            yaml_error(st, {n, 1}, "several YAML documents: a map file holds one")
            | phase: :skip
          }

      line == "..." ->
        %{close_pending(st) | phase: :ended}

      body == "-" or String.starts_with?(body, "- ") ->
        sequence_item(st, String.slice(body, 1..-1//1), n, indent + 2)

      indent > 0 ->
        yaml_error(
          st,
          {n, indent + 1},
          "an indented line that is not a sequence item (- value): a map file's keys are not nested"
        )

      true ->
        key_line(close_pending(%{st | phase: :body}), body, n)
    end
  end

  defp indentation(line) do
    body = String.trim_leading(line, " ")
    {byte_size(line) - byte_size(body), body}
  end

  defp blank?(text), do: String.trim(text) == "" or String.starts_with?(String.trim(text), "#")

  defp sequence_item(%{pending: {key, pos, items}} = st, rest, n, col) do
    case line_end(scalar(rest, col, :block), col) do
      {:ok, value, _rest} -> %{st | pending: {key, pos, [{value, {n, col}} | items]}}
      {:error, c, message} -> yaml_error(st, {n, c}, "#{key}: #{message}")
    end
  end

  defp sequence_item(st, _rest, n, col),
    do: yaml_error(st, {n, col - 1}, "a sequence item (- value) that belongs to no key")

  defp key_line(st, body, n) do
    case Regex.run(~r/\A([A-Za-z_][A-Za-z0-9_]*)[ ]*:(?=[ ]|\z)(.*)\z/s, body) do
      [_, key, rest] ->
        value_col = byte_size(body) - byte_size(rest) + 1

        cond do
          key not in @keys ->
            yaml_error(st, {n, 1}, "unknown key #{inspect(key)}#{did_you_mean(key)}")

          Map.has_key?(st.entries, key) ->
            {_, {line, _}} = st.entries[key]
            yaml_error(st, {n, 1}, "#{key} is given twice (first at line #{line})")

          blank?(rest) ->
            %{st | pending: {key, {n, 1}, []}}

          true ->
            {spaces, text} = indentation(rest)
            value_line(st, key, text, {n, value_col + spaces})
        end

      nil ->
        yaml_error(st, {n, 1}, "expected `key: value` (a map file is one mapping of keys)")
    end
  end

  defp did_you_mean(key) do
    case Enum.max_by(@keys, &String.jaro_distance(&1, key)) do
      best -> if String.jaro_distance(best, key) > 0.8, do: ": did you mean #{best}?", else: ""
    end <> " (known: #{Enum.join(@keys, ", ")})"
  end

  defp value_line(st, key, "[" <> rest, {n, col}) do
    case flow_items(rest, col + 1, []) do
      {:ok, items} ->
        put_entry(st, key, {Enum.map(items, fn {v, c} -> {v, {n, c}} end), {n, col}})

      {:error, c, message} ->
        st |> put_entry(key, {:bad, {n, col}}) |> yaml_error({n, c}, "#{key}: #{message}")
    end
  end

  defp value_line(st, key, text, {n, col}) do
    case line_end(scalar(text, col, :block), col) do
      {:ok, value, _} ->
        put_entry(st, key, {value, {n, col}})

      {:error, c, message} ->
        st |> put_entry(key, {:bad, {n, col}}) |> yaml_error({n, c}, "#{key}: #{message}")
    end
  end

  defp put_entry(st, key, entry), do: %{st | entries: Map.put(st.entries, key, entry)}

  defp close_pending(%{pending: nil} = st), do: st

  defp close_pending(%{pending: {key, pos, []}} = st),
    do: put_entry(%{st | pending: nil}, key, {{:scalar, "", false}, pos})

  defp close_pending(%{pending: {key, pos, items}} = st),
    do: put_entry(%{st | pending: nil}, key, {Enum.reverse(items), pos})

  # the items of a one-line flow sequence, after its [
  defp flow_items(text, col, acc) do
    {spaces, text} = indentation(text)
    col = col + spaces

    case text do
      "]" <> rest ->
        if acc == [] and blank?(rest),
          do: {:ok, []},
          else: {:error, col, "an empty item in a sequence"}

      _ ->
        with {:ok, value, rest} <- scalar(text, col, :flow) do
          {_spaces, after_item} = indentation(rest)
          next = col + byte_size(text) - byte_size(after_item)
          items = [{value, col} | acc]

          case after_item do
            "," <> more ->
              flow_items(more, next + 1, items)

            "]" <> tail ->
              if blank?(tail),
                do: {:ok, Enum.reverse(items)},
                else: {:error, next + 1, "text after the sequence's ]"}

            _ ->
              {:error, next, "expected , or ] (a sequence is written on one line: [x, y, yaw])"}
          end
        end
    end
  end

  # {:scalar, text, quoted?} and the rest of the line, or {:error, column, message}
  defp scalar(text, col, context) do
    {spaces, text} = indentation(text)
    col = col + spaces

    case text do
      "\"" <> rest ->
        double_quoted(rest, col, col + 1, [])

      "'" <> rest ->
        single_quoted(rest, col, [])

      <<c, _::binary>> when c in ~c"[{&*!|>?%@`" ->
        {:error, col, "#{<<c>>} here: only plain or quoted scalars and [x, y] sequences are read"}

      _ ->
        plain(text, col, context)
    end
  end

  defp plain(text, col, context) do
    stop = if context == :flow, do: ~r/,|\]|\s#/, else: ~r/\s#/

    {value, rest} =
      case Regex.run(stop, text, return: :index) do
        [{at, _}] -> {binary_part(text, 0, at), binary_part(text, at, byte_size(text) - at)}
        nil -> {text, ""}
      end

    cond do
      String.contains?(value, ": ") ->
        {:error, col, "a nested mapping (key: value inside a value) is not part of a map file"}

      context == :flow and String.contains?(value, ["[", "{"]) ->
        {:error, col, "a nested sequence: origin is one flat list [x, y, yaw]"}

      context == :block and not blank?(rest) ->
        {:error, col, "unexpected text after the value"}

      true ->
        {:ok, {:scalar, String.trim(value), false}, rest}
    end
  end

  defp double_quoted(<<"\"", rest::binary>>, col, _at, acc), do: quoted_end(acc, rest, col)

  defp double_quoted(<<"\\", c, rest::binary>>, col, at, acc) when c in ~c"\"\\/ntr" do
    char = %{?" => "\"", ?\\ => "\\", ?/ => "/", ?n => "\n", ?t => "\t", ?r => "\r"}[c]
    double_quoted(rest, col, at + 2, [acc | char])
  end

  defp double_quoted(<<"\\", _::binary>>, _col, at, _acc),
    do: {:error, at, "an escape this reader does not know (\\\" \\\\ \\/ \\n \\t \\r are known)"}

  defp double_quoted(<<c::utf8, rest::binary>>, col, at, acc),
    do: double_quoted(rest, col, at + 1, [acc | <<c::utf8>>])

  defp double_quoted(_, col, _at, _acc), do: {:error, col, "a \" string not closed on its line"}

  defp single_quoted(<<"''", rest::binary>>, col, acc), do: single_quoted(rest, col, [acc | "'"])
  defp single_quoted(<<"'", rest::binary>>, col, acc), do: quoted_end(acc, rest, col)

  defp single_quoted(<<c::utf8, rest::binary>>, col, acc),
    do: single_quoted(rest, col, [acc | <<c::utf8>>])

  defp single_quoted(_, col, _acc), do: {:error, col, "a ' string not closed on its line"}

  defp quoted_end(acc, rest, _col), do: {:ok, {:scalar, IO.iodata_to_binary(acc), true}, rest}

  # after a value on a key's or an item's line, only a comment
  defp line_end({:ok, value, rest}, col) do
    if blank?(rest),
      do: {:ok, value, ""},
      else: {:error, col, "unexpected text after the value"}
  end

  defp line_end(error, _col), do: error

  ## map parameters: every key checked, every problem reported

  defp yaml_params(st) do
    {image, st} = param(st, "image", :required, &image/1)
    {res, st} = param(st, "resolution", :required, &resolution/1)
    {origin, st} = param(st, "origin", :required, &origin/1)
    {negate, st} = param(st, "negate", 0, &negate/1)
    {occ, st} = param(st, "occupied_thresh", 0.65, &probability/1)
    {free, st} = param(st, "free_thresh", 0.196, &probability/1)
    {_mode, st} = param(st, "mode", "trinary", &mode/1)

    st =
      if is_number(occ) and is_number(free) and free > occ,
        do:
          yaml_error(
            st,
            elem(st.entries["free_thresh"] || st.entries["occupied_thresh"], 1),
            "free_thresh (#{free}) is above occupied_thresh (#{occ})"
          ),
        else: st

    Map.put(st, :params, %{
      image: image,
      resolution: res,
      origin: origin,
      negate: negate,
      occupied: occ,
      free: free
    })
  end

  defp param(st, key, default, check) do
    case Map.fetch(st.entries, key) do
      :error when default == :required ->
        {nil, yaml_error(st, {0, 0}, "missing #{key}")}

      :error ->
        {default, st}

      {:ok, {:bad, _pos}} ->
        {nil, st}

      {:ok, {value, pos}} ->
        case check.(value) do
          {:ok, v} -> {v, st}
          {:error, message} -> {nil, yaml_error(st, pos, "#{key}: #{message}")}
          {:error, at, message} -> {nil, yaml_error(st, at, "#{key}: #{message}")}
        end
    end
  end

  defp image({:scalar, "", _}), do: {:error, "expected the image's file name, got nothing"}

  defp image({:scalar, name, _}) do
    cond do
      byte_size(name) > 4096 -> {:error, "a file name longer than 4096 bytes"}
      String.contains?(name, <<0>>) -> {:error, "a file name with a NUL byte"}
      true -> {:ok, name}
    end
  end

  defp image(_), do: {:error, "expected the image's file name, got a sequence"}

  defp resolution(value) do
    case number(value) do
      {:ok, r} when r >= @min_resolution and r <= @max_resolution ->
        {:ok, r / 1}

      {:ok, r} ->
        {:error, "#{r} m/cell is out of range (#{@min_resolution} to #{@max_resolution})"}

      {:error, message} ->
        {:error, message}
    end
  end

  defp origin(items) when is_list(items) and length(items) in 2..3 do
    items
    |> Enum.map(fn {v, pos} ->
      case number(v) do
        {:ok, x} when abs(x) <= @max_coordinate -> {:ok, x / 1}
        {:ok, x} -> {:error, pos, "#{x} is beyond ±#{@max_coordinate} m"}
        {:error, message} -> {:error, pos, message}
      end
    end)
    |> Enum.find(&match?({:error, _, _}, &1))
    |> case do
      nil ->
        case Enum.map(items, fn {v, _} -> elem(number(v), 1) / 1 end) do
          [x, y] -> {:ok, {x, y, 0.0}}
          [x, y, yaw] -> {:ok, {x, y, yaw}}
        end

      error ->
        error
    end
  end

  defp origin(_), do: {:error, "expected [x, y] or [x, y, yaw]"}

  defp negate({:scalar, text, _}) when text in ~w(0 false False FALSE), do: {:ok, 0}
  defp negate({:scalar, text, _}) when text in ~w(1 true True TRUE), do: {:ok, 1}
  defp negate(_), do: {:error, "expected 0 or 1"}

  defp probability(value) do
    case number(value) do
      {:ok, p} when p >= 0 and p <= 1 -> {:ok, p / 1}
      {:ok, p} -> {:error, "#{p} is not between 0 and 1"}
      error -> error
    end
  end

  defp mode({:scalar, "trinary", _}), do: {:ok, "trinary"}

  defp mode({:scalar, mode, _}) when mode in ~w(scale raw),
    do: {:error, "mode #{inspect(mode)} is not supported (only \"trinary\" is)"}

  defp mode({:scalar, mode, _}),
    do: {:error, "unknown mode #{inspect(mode)} (map_server knows trinary, scale and raw)"}

  defp mode(_), do: {:error, "expected trinary"}

  # YAML's numbers, as yaml-cpp reads them for map_server (quoted or not)
  defp number({:scalar, text, _}) when byte_size(text) <= 64 do
    cond do
      text =~ ~r/\A[-+]?[0-9]+\z/ ->
        {:ok, String.to_integer(text)}

      text =~ ~r/\A[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?\z/ ->
        to_float(text)

      String.downcase(text) in ~w(.inf +.inf -.inf .nan) ->
        {:error, "#{text} is not a finite number"}

      true ->
        {:error, "expected a number, got #{inspect(text)}"}
    end
  end

  defp number({:scalar, _text, _}), do: {:error, "expected a number, got a text of over 64 bytes"}
  defp number(_), do: {:error, "expected a number, got a sequence"}

  defp to_float(text) do
    {sign, digits} =
      case text do
        "-" <> d -> {"-", d}
        "+" <> d -> {"", d}
        d -> {"", d}
      end

    [mantissa | exponent] = String.split(String.downcase(digits), "e")
    mantissa = if String.starts_with?(mantissa, "."), do: "0" <> mantissa, else: mantissa
    mantissa = if String.contains?(mantissa, "."), do: mantissa, else: mantissa <> "."
    mantissa = if String.ends_with?(mantissa, "."), do: mantissa <> "0", else: mantissa
    exponent = Enum.map_join(exponent, &("e" <> &1))

    {:ok, :erlang.binary_to_float(sign <> mantissa <> exponent)}
  rescue
    ArgumentError -> {:error, "#{text} is not a finite number"}
  end

  ## PGM: a binary (P5) 8-bit grey image, its header checked before its data is read

  defp read_pgm(path) do
    with {:ok, size} <- regular(path, "the map's image"),
         {:ok, prefix} <- pread(path, 0, min(size, @max_header)),
         {:ok, w, h, offset} <- pgm_header(prefix, path, size),
         :ok <- pgm_size(path, size, w, h, offset),
         {:ok, pixels} <- pread(path, offset, w * h) do
      {:ok, w, h, pixels}
    end
  end

  defp pread(_path, _at, 0), do: {:ok, ""}

  defp pread(path, at, count) do
    with {:ok, f} <- :file.open(path, [:read, :raw, :binary]) do
      try do
        case :file.pread(f, at, count) do
          {:ok, bin} when byte_size(bin) == count -> {:ok, bin}
          {:ok, bin} -> {:error, [Error.at_byte(path, at + byte_size(bin), "the file ends here")]}
          :eof -> {:error, [Error.at_byte(path, at, "the file ends here")]}
          {:error, reason} -> {:error, reason}
        end
      after
        :file.close(f)
      end
    end
    |> case do
      {:error, reason} when is_atom(reason) ->
        fail(path, "cannot read the map's image: #{:file.format_error(reason)}")

      other ->
        other
    end
  end

  @other_images [
    {<<0x89, "PNG">>, "a PNG image"},
    {<<0xFF, 0xD8, 0xFF>>, "a JPEG image"},
    {"GIF8", "a GIF image"},
    {"BM", "a BMP image"},
    {<<"II*", 0>>, "a TIFF image"},
    {<<"MM", 0, "*">>, "a TIFF image"},
    {"P1", "an ASCII bitmap (PBM P1)"},
    {"P2", "an ASCII grey map (PGM P2)"},
    {"P3", "an ASCII colour image (PPM P3)"},
    {"P4", "a bitmap (PBM P4)"},
    {"P6", "a colour image (PPM P6)"},
    {"P7", "a PAM image (P7)"}
  ]

  defp pgm_header(<<"P5", c, _::binary>> = prefix, path, size) when c in @whitespace do
    with {:ok, w, at} <- header_int(prefix, 2, "width", path, size),
         {:ok, h, at} <- header_int(prefix, at, "height", path, size),
         :ok <- cells(path, at, w, h),
         {:ok, maxval, at} <- header_int(prefix, at, "maximum value", path, size) do
      if maxval == 255,
        do: {:ok, w, h, at + 1},
        else:
          {:error,
           [Error.at_byte(path, at, "maximum value #{maxval}: only 8-bit maps (255) are read")]}
    end
  end

  defp pgm_header(prefix, path, _size) do
    kind =
      Enum.find_value(@other_images, "not a PGM image", fn {magic, kind} ->
        if String.starts_with?(prefix, magic), do: kind
      end)

    {:error,
     [
       Error.at_byte(
         path,
         0,
         "#{kind}: a map image must be a binary 8-bit PGM (P5), as map_saver writes it " <>
           "(convert it, e.g. with `convert image.png -depth 8 map.pgm`)"
       )
     ]}
  end

  # the number at or after `at` (after whitespace and # comments), and where it ends
  defp header_int(prefix, at, what, path, size) do
    cond do
      at >= byte_size(prefix) ->
        header_cut(prefix, at, what, path, size)

      :binary.at(prefix, at) in @whitespace ->
        header_int(prefix, at + 1, what, path, size)

      :binary.at(prefix, at) == ?# ->
        case :binary.match(prefix, ["\n", "\r"], scope: {at, byte_size(prefix) - at}) do
          {nl, 1} -> header_int(prefix, nl + 1, what, path, size)
          :nomatch -> header_cut(prefix, byte_size(prefix), what, path, size)
        end

      true ->
        digits(prefix, at, at, what, path, size)
    end
  end

  defp digits(prefix, start, at, what, path, size) do
    cond do
      at < byte_size(prefix) and :binary.at(prefix, at) in ?0..?9 and at - start < 10 ->
        digits(prefix, start, at + 1, what, path, size)

      at == start ->
        {:error, [Error.at_byte(path, at, "#{what}: expected a decimal number")]}

      at - start >= 10 ->
        {:error, [Error.at_byte(path, start, "#{what}: a number of over 9 digits")]}

      at >= byte_size(prefix) ->
        header_cut(prefix, at, what, path, size)

      :binary.at(prefix, at) not in [?# | @whitespace] ->
        {:error, [Error.at_byte(path, at, "#{what}: expected whitespace after the number")]}

      true ->
        case String.to_integer(binary_part(prefix, start, at - start)) do
          0 -> {:error, [Error.at_byte(path, start, "#{what}: must be at least 1")]}
          n -> {:ok, n, at}
        end
    end
  end

  defp header_cut(prefix, at, what, path, size) do
    message =
      if size > byte_size(prefix),
        do: "the PGM header is longer than #{@max_header} bytes (comments included)",
        else: "the file ends in the PGM header, before the end of the #{what}"

    {:error, [Error.at_byte(path, at, message)]}
  end

  defp cells(_path, _at, w, h) when w * h <= @max_cells, do: :ok

  defp cells(path, at, w, h),
    do:
      {:error,
       [
         Error.at_byte(
           path,
           at,
           "#{w} x #{h} = #{w * h} cells: a map is limited to #{@max_cells} cells"
         )
       ]}

  defp pgm_size(path, size, w, h, offset) do
    expected = offset + w * h

    cond do
      size < expected ->
        {:error,
         [
           Error.at_byte(
             path,
             size,
             "the image data ends after #{size - offset} of #{w * h} bytes (#{w} x #{h} pixels)"
           )
         ]}

      size > expected ->
        {:error,
         [
           Error.at_byte(
             path,
             expected,
             "#{size - expected} bytes after the image data (#{w} x #{h} pixels end here)"
           )
         ]}

      true ->
        :ok
    end
  end

  ## Cells

  defp to_cells(pixels, width, height, params) do
    lut = List.to_tuple(for v <- 0..255, do: trinary(v, params))

    for row <- (height - 1)..0//-1, into: <<>> do
      for <<v <- binary_part(pixels, row * width, width)>>,
        into: <<>>,
        do: <<elem(lut, v)::signed-8>>
    end
  end

  defp trinary(v, %{negate: negate, occupied: occ, free: free}) do
    p = if negate == 1, do: v / 255, else: (255 - v) / 255

    cond do
      p > occ -> 100
      p < free -> 0
      true -> -1
    end
  end
end
