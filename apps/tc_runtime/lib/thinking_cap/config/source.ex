defmodule ThinkingCap.Config.Source do
  @moduledoc false
  # Reads a description file within bounds, before anything parses it: its
  # size (at most @max_bytes), its encoding (UTF-8) and how deep its
  # brackets nest (at most @max_depth). Any byte sequence is refused in
  # time and memory linear in its size, with the line of the problem.

  alias ThinkingCap.Config.Error

  @max_bytes 4 * 1024 * 1024
  @max_depth 64

  @doc false
  @spec read(Path.t()) :: {:ok, String.t()} | {:error, [Error.t()]}
  def read(path) do
    with {:ok, size} <- size(path),
         :ok <- small(path, size),
         {:ok, source} <- read_file(path),
         :ok <- utf8(path, source),
         :ok <- nesting(path, source) do
      {:ok, source}
    end
  end

  defp size(path) do
    case File.stat(path) do
      {:ok, %File.Stat{type: :regular, size: size}} ->
        {:ok, size}

      {:ok, %File.Stat{type: type}} ->
        fail(path, {0, 0}, "not a regular file (#{type})")

      {:error, reason} ->
        fail(path, {0, 0}, "cannot read the file: #{:file.format_error(reason)}")
    end
  end

  defp small(_path, size) when size <= @max_bytes, do: :ok

  defp small(path, size),
    do:
      fail(
        path,
        {0, 0},
        "the file holds #{size} bytes: description files are limited to #{@max_bytes} " <>
          "(import big maps with map: [yaml: ...])"
      )

  defp read_file(path) do
    case File.read(path) do
      {:ok, source} ->
        {:ok, source}

      {:error, reason} ->
        fail(path, {0, 0}, "cannot read the file: #{:file.format_error(reason)}")
    end
  end

  @doc false
  # :ok, or the line and column where `source` stops being UTF-8 (shared
  # by every bounded reader: description files, maps, URDFs)
  @spec utf8(Path.t(), binary()) :: :ok | {:error, [Error.t()]}
  def utf8(path, source) do
    case :unicode.characters_to_binary(source) do
      binary when is_binary(binary) ->
        :ok

      {_error, good, _rest} ->
        fail(path, line_column(good), "not UTF-8 text: invalid bytes here")
    end
  end

  # the line and column just after `prefix`
  defp line_column(prefix) do
    lines = :binary.split(prefix, "\n", [:global])
    {length(lines), String.length(List.last(lines)) + 1}
  end

  # the deepest nesting of ( [ { and << outside strings, charlists and
  # comments; refused at the first bracket past @max_depth
  defp nesting(path, source) do
    case scan(source, 0, 1, nil) do
      :ok ->
        :ok

      {:deep, line} ->
        fail(
          path,
          {line, 1},
          "brackets nested deeper than #{@max_depth}: description files hold flat data"
        )
    end
  end

  defp scan(<<>>, _depth, _line, _quote), do: :ok
  defp scan(<<?\n, rest::binary>>, d, line, q), do: scan(rest, d, line + 1, q)

  # inside a string or charlist: escapes skip a byte, the quote ends it
  defp scan(<<?\\, ?\n, rest::binary>>, d, line, q) when q != nil, do: scan(rest, d, line + 1, q)
  defp scan(<<?\\, _, rest::binary>>, d, line, q) when q != nil, do: scan(rest, d, line, q)
  defp scan(<<c, rest::binary>>, d, line, c), do: scan(rest, d, line, nil)
  defp scan(<<_, rest::binary>>, d, line, q) when q != nil, do: scan(rest, d, line, q)

  # outside: comments, character literals, quotes, brackets
  defp scan(<<?#, rest::binary>>, d, line, nil), do: scan(skip_line(rest), d, line, nil)
  defp scan(<<??, ?\\, _, rest::binary>>, d, line, nil), do: scan(rest, d, line, nil)
  defp scan(<<??, _::utf8, rest::binary>>, d, line, nil), do: scan(rest, d, line, nil)
  defp scan(<<c, rest::binary>>, d, line, nil) when c in [?", ?'], do: scan(rest, d, line, c)
  defp scan(<<"<<", _::binary>>, d, line, nil) when d >= @max_depth, do: {:deep, line}
  defp scan(<<"<<", rest::binary>>, d, line, nil), do: scan(rest, d + 1, line, nil)
  defp scan(<<">>", rest::binary>>, d, line, nil), do: scan(rest, max(d - 1, 0), line, nil)

  defp scan(<<c, _::binary>>, d, line, nil) when c in ~c"([{" and d >= @max_depth,
    do: {:deep, line}

  defp scan(<<c, rest::binary>>, d, line, nil) when c in ~c"([{", do: scan(rest, d + 1, line, nil)

  defp scan(<<c, rest::binary>>, d, line, nil) when c in ~c")]}",
    do: scan(rest, max(d - 1, 0), line, nil)

  defp scan(<<_, rest::binary>>, d, line, nil), do: scan(rest, d, line, nil)

  # a comment runs to the end of its line (the newline is scanned)
  defp skip_line(rest) do
    case :binary.match(rest, "\n") do
      {at, _} -> binary_part(rest, at, byte_size(rest) - at)
      :nomatch -> <<>>
    end
  end

  defp fail(path, position, message), do: {:error, [Error.new(path, position, message)]}
end
