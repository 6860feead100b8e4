defmodule ThinkingCap.Config.Literal do
  @moduledoc false
  # Turns the quoted form of a description file into plain data without
  # evaluating anything: numbers, atoms, strings, lists, tuples, maps,
  # keyword lists, module names (aliases) and negative numbers. Anything
  # else (calls, variables, interpolation, attributes, operators) is an
  # error at its position. Returns the data and the position of every value
  # (by path: keyword keys, list indexes, map keys, tuple indexes) and of
  # every keyword key ({:key, path}).

  alias ThinkingCap.Config.Error

  @type path :: [term()]
  @type positions :: %{optional(path() | {:key, path()}) => {pos_integer(), pos_integer()}}

  # Input is bounded before it is parsed (ThinkingCap.Config.Source: size,
  # UTF-8, nesting), and the parser makes no atom it is not allowed to:
  # a name that is not an atom yet (a waypoint's, a sensor's; a variable's,
  # which is then refused) is made one only while the file has made fewer
  # than @new_atoms of them.
  @new_atoms 2_000

  @doc false
  @spec parse(String.t(), Path.t()) :: {:ok, term(), positions()} | {:error, [Error.t()]}
  def parse(source, file) do
    budget = :counters.new(1, [])

    opts = [
      file: file,
      columns: true,
      token_metadata: true,
      existing_atoms_only: true,
      static_atoms_encoder: &encode_atom(&1, &2, budget),
      literal_encoder: &{:ok, {:__block__, &2, [&1]}}
    ]

    case Code.string_to_quoted(source, opts) do
      {:ok, quoted} ->
        case convert(quoted, [], {1, 1}, %{file: file, positions: %{}, errors: []}) do
          {value, %{errors: []} = acc} -> {:ok, value, acc.positions}
          {_value, acc} -> {:error, Enum.reverse(acc.errors)}
        end

      {:error, {meta, message, token}} ->
        {:error,
         [
           Error.new(
             file,
             position(meta, {1, 1}),
             "syntax error: #{syntax_message(message, token)}"
           )
         ]}
    end
  end

  defp encode_atom(name, _meta, _budget) when byte_size(name) > 255,
    do: {:error, "a name longer than 255 bytes: "}

  defp encode_atom(name, _meta, budget) do
    {:ok, String.to_existing_atom(name)}
  rescue
    ArgumentError ->
      if :counters.get(budget, 1) < @new_atoms do
        :counters.add(budget, 1, 1)
        {:ok, String.to_atom(name)}
      else
        {:error, "more than #{@new_atoms} distinct new names in one file, at "}
      end
  end

  defp syntax_message("unsafe atom does not exist: ", token),
    do: "unknown name #{token}: write an atom as :#{token} or a string in quotes"

  defp syntax_message(message, token) when is_binary(message), do: String.trim(message <> token)
  defp syntax_message({prefix, suffix}, token), do: String.trim("#{prefix}#{token}#{suffix}")

  # An encoded literal (or a block of one expression).
  defp convert({:__block__, meta, [inner]}, path, pos, acc) do
    pos = position(meta, pos)
    acc = put_position(acc, path, pos)

    cond do
      is_list(inner) ->
        convert_list(inner, path, pos, acc)

      is_tuple(inner) and tuple_size(inner) == 2 ->
        convert_tuple(Tuple.to_list(inner), path, pos, acc)

      scalar?(inner) ->
        {inner, acc}

      true ->
        convert(inner, path, pos, acc)
    end
  end

  defp convert({:__block__, meta, exprs}, _path, pos, acc) when length(exprs) != 1 do
    {nil,
     error(
       acc,
       position(meta, pos),
       "expected one value (a keyword list), found #{length(exprs)} expressions"
     )}
  end

  defp convert({:{}, meta, elems}, path, pos, acc) do
    pos = position(meta, pos)
    convert_tuple(elems, path, pos, put_position(acc, path, pos))
  end

  defp convert({:%{}, meta, pairs}, path, pos, acc) do
    pos = position(meta, pos)
    acc = put_position(acc, path, pos)

    Enum.reduce(pairs, {%{}, acc}, fn
      {k, v}, {map, acc} ->
        {key, acc} = convert(k, path ++ [:__map_key__], pos, acc)
        {value, acc} = convert(v, path ++ [key], pos, acc)
        {Map.put(map, key, value), acc}

      other, {map, acc} ->
        {map,
         error(
           acc,
           node_position(other, pos),
           "expected key => value in a map, got #{describe(other)}"
         )}
    end)
  end

  defp convert({:__aliases__, meta, parts}, path, pos, acc) do
    pos = position(meta, pos)

    if Enum.all?(parts, &is_atom/1) do
      {Module.concat(parts), put_position(acc, path, pos)}
    else
      {nil,
       error(acc, pos, "expected a module name, got #{describe({:__aliases__, meta, parts})}")}
    end
  end

  defp convert({sign, meta, [operand]} = node, path, pos, acc) when sign in [:-, :+] do
    pos = position(meta, pos)

    case convert(operand, path, pos, %{acc | errors: []}) do
      {n, %{errors: []} = inner} when is_number(n) ->
        {if(sign == :-, do: -n, else: n), put_position(%{inner | errors: acc.errors}, path, pos)}

      _ ->
        {nil, error(acc, pos, "expected a literal value, got the expression #{describe(node)}")}
    end
  end

  # keyword pair or other raw 2-tuple
  defp convert({left, right}, path, pos, acc), do: convert_tuple([left, right], path, pos, acc)

  defp convert(list, path, pos, acc) when is_list(list), do: convert_list(list, path, pos, acc)

  defp convert(value, path, pos, acc) when is_number(value) or is_atom(value) or is_binary(value),
    do: {value, put_new_position(acc, path, pos)}

  defp convert({name, meta, args} = node, _path, pos, acc) when is_list(meta) do
    {nil, error(acc, start(node, position(meta, pos)), not_literal(name, args, node))}
  end

  defp convert(other, _path, pos, acc),
    do: {nil, error(acc, pos, "expected a literal value, got #{describe(other)}")}

  defp convert_list(items, path, pos, acc) do
    {values, acc} =
      items
      |> Enum.with_index()
      |> Enum.map_reduce(acc, fn
        # keyword entry: the key is an encoded atom
        {{{:__block__, key_meta, [key]}, value}, _i}, acc when is_atom(key) ->
          if Keyword.get(key_meta, :format) == :keyword do
            key_pos = position(key_meta, pos)
            acc = %{acc | positions: Map.put(acc.positions, {:key, path ++ [key]}, key_pos)}
            {v, acc} = convert(value, path ++ [key], key_pos, acc)
            {{key, v}, acc}
          else
            {k, acc} = convert({:__block__, key_meta, [key]}, path ++ [{:elem, 0}], pos, acc)
            {v, acc} = convert(value, path ++ [{:elem, 1}], pos, acc)
            {{k, v}, acc}
          end

        {item, i}, acc ->
          convert(item, path ++ [i], pos, acc)
      end)

    {values, acc}
  end

  defp convert_tuple(elems, path, pos, acc) do
    {values, acc} =
      elems
      |> Enum.with_index()
      |> Enum.map_reduce(acc, fn {elem, i}, acc -> convert(elem, path ++ [i], pos, acc) end)

    {List.to_tuple(values), acc}
  end

  defp scalar?(v), do: is_number(v) or is_atom(v) or is_binary(v)

  defp not_literal(:<<>>, _args, _node),
    do: "string interpolation and binaries are not allowed: write a plain string"

  defp not_literal(:@, _args, _node),
    do: "module attributes are not allowed: write the value itself"

  defp not_literal(:&, _args, _node),
    do: "functions are not allowed: description files hold data only"

  defp not_literal(:fn, _args, _node),
    do: "functions are not allowed: description files hold data only"

  defp not_literal(name, args, _node) when is_atom(name) and is_atom(args),
    do:
      "variables are not allowed (found #{name}): description files hold data only; write an atom as :#{name}"

  defp not_literal(_name, _args, node),
    do:
      "expected a literal value, got the expression #{describe(node)}: description files are never evaluated"

  defp describe(node),
    do: node |> Macro.to_string() |> String.replace(~r/\s+/, " ") |> String.slice(0, 60)

  # where an expression starts: a remote call `Mod.fun(...)` at `Mod`
  defp start({{:., _, [left, _name]}, _meta, _args}, pos), do: start(left, pos)
  defp start({_, meta, _} = node, pos) when is_list(meta), do: node_position(node, pos)
  defp start(_node, pos), do: pos

  defp node_position({_, meta, _}, pos) when is_list(meta), do: position(meta, pos)
  defp node_position(_, pos), do: pos

  defp position(meta, default) do
    case {Keyword.get(meta, :line), Keyword.get(meta, :column)} do
      {line, column} when is_integer(line) and is_integer(column) -> {line, column}
      {line, nil} when is_integer(line) -> {line, 1}
      _ -> default
    end
  end

  defp put_position(acc, path, pos), do: %{acc | positions: Map.put(acc.positions, path, pos)}

  defp put_new_position(acc, path, pos),
    do: %{acc | positions: Map.put_new(acc.positions, path, pos)}

  defp error(acc, pos, message),
    do: %{acc | errors: [Error.new(acc.file, pos, message) | acc.errors]}
end
