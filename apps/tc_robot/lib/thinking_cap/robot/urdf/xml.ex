defmodule ThinkingCap.Robot.URDF.XML do
  @moduledoc """
  A small, bounded XML reader for URDF files: elements and attributes
  into a tree of strings, nothing else.

  Why not xmerl: `xmerl_scan` makes an atom of every element and attribute
  name; `xmerl_sax_parser` (xmerl 1.3.30, OTP 25) keeps names as strings
  but reads DTDs and expands internal entities (three nested entities of
  ten make 30,000 characters, 0.47 s: a few more levels exhaust memory),
  and cannot be stopped from its event function. A URDF needs none of
  that, so this reader takes only what URDF files hold and refuses the
  rest with its line:

    * elements, attributes (values with XML's five entities and character
      references), text (ignored), comments, CDATA, processing
      instructions, an XML declaration and a byte-order mark;
    * no DOCTYPE, DTD or entity declaration: nothing names another file,
      nothing expands;
    * at most 64 elements deep, 100,000 elements, 256 attributes per
      element, 256-byte names; the input is UTF-8 (checked before).

  Time and memory are linear in the input; the first malformed place ends
  the reading (XML's rule: a malformed document has no meaning). Element
  and attribute names stay binaries: no atom comes from a file.
  """

  @max_depth 64
  @max_elements 100_000
  @max_attributes 256
  @max_name 256

  @typedoc """
  An element: its name, its attributes (name => value, plus the line the
  element starts on under the key `:line`) and its child elements.
  """
  @type element ::
          {String.t(), %{optional(String.t()) => String.t(), :line => pos_integer()}, [element()]}

  @doc "Parses `xml` (UTF-8); a malformed document gives its first problem's line."
  @spec parse(binary()) :: {:ok, element()} | {:error, pos_integer(), String.t()}
  def parse(<<0xEF, 0xBB, 0xBF, rest::binary>>), do: misc(rest, 1, :before)
  def parse(xml) when is_binary(xml), do: misc(xml, 1, :before)

  ## outside the root element

  defp misc(<<c, rest::binary>>, line, phase) when c in ~c" \t\r", do: misc(rest, line, phase)
  defp misc(<<?\n, rest::binary>>, line, phase), do: misc(rest, line + 1, phase)

  defp misc(<<"<!--", rest::binary>>, line, phase) do
    with {:ok, rest, line} <- skip_to(rest, "-->", line, "a comment"), do: misc(rest, line, phase)
  end

  defp misc(<<"<?", rest::binary>>, line, phase) do
    with {:ok, rest, line} <- skip_to(rest, "?>", line, "a processing instruction"),
         do: misc(rest, line, phase)
  end

  defp misc(<<"<!DOCTYPE", _::binary>>, line, _phase),
    do:
      {:error, line,
       "a DOCTYPE: a URDF needs none, and DTDs and entities are not read " <>
         "(they could name other files or expand without bound)"}

  defp misc(<<"<!", _::binary>>, line, _phase), do: {:error, line, "a declaration (<!...) here"}

  defp misc(<<"<", rest::binary>>, line, :before) do
    case start_tag(rest, line, [], 0, 0) do
      {:done, root, rest, line} -> misc(rest, line, {:after, root})
      {:open, stack, rest, line, depth, count} -> content(rest, line, stack, depth, count)
      error -> error
    end
  end

  defp misc(<<>>, _line, {:after, root}), do: {:ok, root}
  defp misc(<<>>, line, :before), do: {:error, line, "no root element"}
  defp misc(_, line, {:after, _}), do: {:error, line, "content after the root element"}
  defp misc(_, line, :before), do: {:error, line, "text before the root element"}

  ## inside elements: `stack` holds the open ones, innermost first

  defp content(<<"<!--", rest::binary>>, line, stack, depth, count) do
    with {:ok, rest, line} <- skip_to(rest, "-->", line, "a comment"),
         do: content(rest, line, stack, depth, count)
  end

  defp content(<<"<![CDATA[", rest::binary>>, line, stack, depth, count) do
    with {:ok, rest, line} <- skip_to(rest, "]]>", line, "a CDATA section"),
         do: content(rest, line, stack, depth, count)
  end

  defp content(<<"<?", rest::binary>>, line, stack, depth, count) do
    with {:ok, rest, line} <- skip_to(rest, "?>", line, "a processing instruction"),
         do: content(rest, line, stack, depth, count)
  end

  defp content(<<"<!", _::binary>>, line, _stack, _depth, _count),
    do: {:error, line, "a declaration (<!...) inside an element: DTDs and entities are not read"}

  defp content(<<"</", rest::binary>>, line, stack, depth, count),
    do: end_tag(rest, line, stack, depth, count)

  defp content(<<"<", rest::binary>>, line, stack, depth, count) do
    case start_tag(rest, line, stack, depth, count) do
      {:open, stack, rest, line, depth, count} -> content(rest, line, stack, depth, count)
      error -> error
    end
  end

  defp content(text, line, [{name, attrs, _} | _] = stack, depth, count) do
    case :binary.match(text, "<") do
      {at, _} ->
        content(
          binary_part(text, at, byte_size(text) - at),
          line + newlines(binary_part(text, 0, at)),
          stack,
          depth,
          count
        )

      :nomatch ->
        {:error, line + newlines(text),
         "the file ends inside <#{name}> (opened at line #{attrs.line})"}
    end
  end

  defp start_tag(bin, line, stack, depth, count) do
    cond do
      depth >= @max_depth ->
        {:error, line, "elements nested deeper than #{@max_depth}"}

      count >= @max_elements ->
        {:error, line, "more than #{@max_elements} elements"}

      true ->
        with {:ok, name, rest} <- name(bin, line, "an element name after <"),
             {:ok, attrs, rest, end_line, kind} <- attributes(rest, line, %{line: line}, name) do
          element = {name, attrs, []}

          case {kind, stack} do
            {:empty, []} -> {:done, element, rest, end_line}
            {:empty, _} -> {:open, add_child(stack, element), rest, end_line, depth, count + 1}
            {:open, _} -> {:open, [element | stack], rest, end_line, depth + 1, count + 1}
          end
        end
    end
  end

  defp end_tag(bin, line, [{open, attrs, children} | stack], depth, count) do
    with {:ok, name, rest} <- name(bin, line, "an element name after </"),
         {rest, line} = spaces(rest, line),
         {:ok, rest} <- expect(rest, ">", line, "> to end </#{name}") do
      element = {open, attrs, Enum.reverse(children)}

      cond do
        name != open ->
          {:error, line, "</#{name}> closes <#{open}> (opened at line #{attrs.line})"}

        stack == [] ->
          misc(rest, line, {:after, element})

        true ->
          content(rest, line, add_child(stack, element), depth - 1, count)
      end
    end
  end

  defp add_child([{n, a, children} | stack], element), do: [{n, a, [element | children]} | stack]

  defp attributes(bin, line, attrs, element) do
    {rest, line} = spaces(bin, line)

    case rest do
      "/>" <> rest ->
        {:ok, attrs, rest, line, :empty}

      ">" <> rest ->
        {:ok, attrs, rest, line, :open}

      "" ->
        {:error, line, "the file ends inside the tag <#{element}>"}

      _ when map_size(attrs) > @max_attributes ->
        {:error, line, "more than #{@max_attributes} attributes in <#{element}>"}

      _ ->
        with {:ok, name, rest} <- name(rest, line, "an attribute, /> or > in <#{element}>"),
             {rest, line} = spaces(rest, line),
             {:ok, rest} <- expect(rest, "=", line, "= after the attribute #{name}"),
             {rest, line} = spaces(rest, line),
             {:ok, value, rest, value_line} <- value(rest, line, name) do
          if Map.has_key?(attrs, name),
            do: {:error, line, "the attribute #{name} is given twice in <#{element}>"},
            else: attributes(rest, value_line, Map.put(attrs, name, value), element)
        end
    end
  end

  defp value(<<q, rest::binary>>, line, name) when q in [?", ?'] do
    case :binary.match(rest, <<q>>) do
      {at, _} ->
        raw = binary_part(rest, 0, at)
        rest = binary_part(rest, at + 1, byte_size(rest) - at - 1)

        cond do
          String.contains?(raw, "<") ->
            {:error, line, "a < inside the value of #{name}"}

          true ->
            with {:ok, value} <- references(raw, line, []),
                 do: {:ok, value, rest, line + newlines(raw)}
        end

      :nomatch ->
        {:error, line, "the value of #{name} is never closed"}
    end
  end

  defp value(_, line, name), do: {:error, line, "the value of #{name} must be quoted"}

  @entities %{"lt" => "<", "gt" => ">", "amp" => "&", "quot" => "\"", "apos" => "'"}

  defp references(raw, line, acc) do
    case :binary.split(raw, "&") do
      [done] ->
        {:ok, IO.iodata_to_binary([acc | done])}

      [before, after_amp] ->
        with {at, _} <- :binary.match(after_amp, ";", scope: {0, min(byte_size(after_amp), 12)}),
             {:ok, char} <- reference(binary_part(after_amp, 0, at)) do
          rest = binary_part(after_amp, at + 1, byte_size(after_amp) - at - 1)
          references(rest, line, [acc, before, char])
        else
          _ ->
            {:error, line,
             "an entity reference (&...;) other than &lt; &gt; &amp; &quot; &apos; or &#N;"}
        end
    end
  end

  defp reference("#x" <> hex), do: codepoint(Integer.parse(hex, 16))
  defp reference("#" <> dec), do: codepoint(Integer.parse(dec))
  defp reference(name), do: Map.fetch(@entities, name)

  defp codepoint({n, ""}) when n in 1..0xD7FF or n in 0xE000..0x10FFFF, do: {:ok, <<n::utf8>>}
  defp codepoint(_), do: :error

  defp name(bin, line, expected) do
    case name_length(bin, 0) do
      0 ->
        {:error, line, "expected #{expected}"}

      n when n > @max_name ->
        {:error, line, "a name longer than #{@max_name} bytes"}

      n ->
        {:ok, binary_part(bin, 0, n), binary_part(bin, n, byte_size(bin) - n)}
    end
  end

  defp name_length(<<c, _::binary>>, n) when c in ~c" \t\r\n/>=<\"'&!?", do: n
  defp name_length(<<_, rest::binary>>, n) when n <= @max_name, do: name_length(rest, n + 1)
  defp name_length(_, n), do: n

  defp spaces(<<c, rest::binary>>, line) when c in ~c" \t\r", do: spaces(rest, line)
  defp spaces(<<?\n, rest::binary>>, line), do: spaces(rest, line + 1)
  defp spaces(rest, line), do: {rest, line}

  defp expect(bin, token, line, what) do
    if String.starts_with?(bin, token),
      do: {:ok, binary_part(bin, byte_size(token), byte_size(bin) - byte_size(token))},
      else: {:error, line, "expected #{what}"}
  end

  defp skip_to(bin, terminator, line, what) do
    case :binary.match(bin, terminator) do
      {at, len} ->
        {:ok, binary_part(bin, at + len, byte_size(bin) - at - len),
         line + newlines(binary_part(bin, 0, at))}

      :nomatch ->
        {:error, line, "#{what} that never ends"}
    end
  end

  defp newlines(bin), do: newlines(bin, 0)

  defp newlines(bin, n) do
    case :binary.match(bin, "\n") do
      {at, _} -> newlines(binary_part(bin, at + 1, byte_size(bin) - at - 1), n + 1)
      :nomatch -> n
    end
  end
end
