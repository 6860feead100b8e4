defmodule ThinkingCap.BlackBox.Core.Terms do
  @moduledoc false
  # Whole terms read back from a recording (`:erlang.term_to_binary/1`),
  # which comes from outside: decoded with `:safe` (no atom made, no
  # function reference), and when that fails for want of atoms, the
  # binary's atoms are read first (a walk over the external term format)
  # and made only while they stay within a budget: a file can make at most
  # that many new atoms in all, not fill the VM's atom table. Funs,
  # compressed terms and anything not understood are refused.

  @type budget :: non_neg_integer()

  # Decodes `bin`; `{:ok, term, budget_left}` or `{:error, message}`.
  @spec decode(binary(), budget()) :: {:ok, term(), budget()} | {:error, String.t()}
  def decode(bin, budget) when is_binary(bin) do
    {:ok, :erlang.binary_to_term(bin, [:safe]), budget}
  rescue
    ArgumentError -> with_atoms(bin, budget)
  end

  defp with_atoms(bin, budget) do
    with {:ok, names} <- atoms(bin),
         new = Enum.reject(Enum.uniq(names), &existing?/1),
         :ok <- within(length(new), budget) do
      Enum.each(new, &String.to_atom/1)

      try do
        {:ok, :erlang.binary_to_term(bin, [:safe]), budget - length(new)}
      rescue
        ArgumentError -> {:error, "not a term in Erlang's external format"}
      end
    end
  end

  defp within(n, budget) when n <= budget, do: :ok

  defp within(_n, _budget),
    do:
      {:error,
       "it names more atoms unknown to this VM than a recording may (the budget is spent)"}

  defp existing?(name) do
    _ = String.to_existing_atom(name)
    true
  rescue
    ArgumentError -> false
  end

  # The names of the atoms in an external term, or an error.
  @spec atoms(binary()) :: {:ok, [String.t()]} | {:error, String.t()}
  def atoms(<<131, rest::binary>>) do
    case walk(rest, 1, []) do
      {:ok, names} -> {:ok, names}
      :error -> {:error, "not a term in Erlang's external format (or one with funs)"}
    end
  end

  def atoms(_bin), do: {:error, "not a term in Erlang's external format"}

  # `n` terms left to read from the front of `bin`
  defp walk(<<>>, 0, names), do: {:ok, names}
  defp walk(_bin, 0, _names), do: :error

  defp walk(bin, n, names) do
    case term(bin) do
      {:atom, name, rest} ->
        if String.valid?(name), do: walk(rest, n - 1, [name | names]), else: :error

      {:skip, rest} ->
        walk(rest, n - 1, names)

      {:more, count, rest} ->
        walk(rest, n - 1 + count, names)

      {:node, rest, more} ->
        # a pid, port or reference: its node's name, then fixed bytes
        case term(rest) do
          {:atom, name, <<_::binary-size(more), rest::binary>>} ->
            walk(rest, n - 1, [name | names])

          _ ->
            :error
        end

      :error ->
        :error
    end
  end

  # one term's head: an atom, bytes to skip, or how many terms follow
  defp term(<<97, _, rest::binary>>), do: {:skip, rest}
  defp term(<<98, _::32, rest::binary>>), do: {:skip, rest}
  defp term(<<70, _::64, rest::binary>>), do: {:skip, rest}
  defp term(<<99, _::binary-31, rest::binary>>), do: {:skip, rest}
  defp term(<<106, rest::binary>>), do: {:skip, rest}
  defp term(<<107, len::16, _::binary-size(len), rest::binary>>), do: {:skip, rest}
  defp term(<<109, len::32, _::binary-size(len), rest::binary>>), do: {:skip, rest}
  defp term(<<77, len::32, _, _::binary-size(len), rest::binary>>), do: {:skip, rest}
  defp term(<<110, n, _, _::binary-size(n), rest::binary>>), do: {:skip, rest}
  defp term(<<111, n::32, _, _::binary-size(n), rest::binary>>), do: {:skip, rest}
  defp term(<<118, len::16, name::binary-size(len), rest::binary>>), do: {:atom, name, rest}
  defp term(<<119, len, name::binary-size(len), rest::binary>>), do: {:atom, name, rest}
  defp term(<<100, len::16, name::binary-size(len), rest::binary>>), do: latin1(name, rest)
  defp term(<<115, len, name::binary-size(len), rest::binary>>), do: latin1(name, rest)
  defp term(<<104, arity, rest::binary>>), do: {:more, arity, rest}
  defp term(<<105, arity::32, rest::binary>>), do: {:more, arity, rest}
  defp term(<<116, arity::32, rest::binary>>), do: {:more, 2 * arity, rest}
  # a list: its elements and its tail
  defp term(<<108, len::32, rest::binary>>), do: {:more, len + 1, rest}
  # pids, ports, references: the node's atom, then fixed sizes
  defp term(<<88, rest::binary>>), do: {:node, rest, 12}
  defp term(<<103, rest::binary>>), do: {:node, rest, 9}
  defp term(<<89, rest::binary>>), do: {:node, rest, 8}
  defp term(<<102, rest::binary>>), do: {:node, rest, 5}
  defp term(<<120, rest::binary>>), do: {:node, rest, 12}
  defp term(<<90, len::16, rest::binary>>), do: {:node, rest, 4 + 4 * len}
  defp term(<<114, len::16, rest::binary>>), do: {:node, rest, 1 + 4 * len}
  defp term(<<101, rest::binary>>), do: {:node, rest, 5}
  # M:F/A: two atoms and an integer
  defp term(<<113, rest::binary>>), do: {:more, 3, rest}
  defp term(_other), do: :error

  defp latin1(name, rest), do: {:atom, :unicode.characters_to_binary(name, :latin1), rest}
end
